/* The int8 flow network's layers, each in one pass over its rows (see int8_mlp.py).
 *
 * A layer is onnxruntime's DynamicQuantizeMatMul followed by QuickGelu (alpha 1, SiLU),
 * the last one without: the layer's input x (M, K) float32 is quantised to uint8 with one
 * scale and zero point for the whole call (min and max over all of x, widened to hold 0),
 * multiplied by the int8 weights W (K, N) (zero point 0, a scale per column) in int32,
 * then y = float(acc - zp * colsum(W)) * (scale * w_scale) + bias, and
 * silu(y) = y * logistic(y) with MLAS's rational logistic (MlasLogisticConstants,
 * LogisticKernelFma3's fused multiply-adds). Every step is onnxruntime's own arithmetic,
 * in its order, so a call gives the same bits as the session does (the tests pin it).
 *
 * The product is the exact integer sum on every path: on AMX (tdpbusd, 16 x 16 tiles of
 * u8 x s8 -> s32) where the processor and the kernel allow it, else on AVX-512 VNNI
 * (vpdpbusd: four u8 x s8 products summed into each int32 lane, without saturation),
 * else on AVX2 (vpmaddwd on the operands widened to int16: each pair's sum is exact in
 * int32), else on plain C loops; so every path gives the same bits. onnxruntime's own
 * kernel is exact only on processors with VNNI or AMX: on AVX2 alone it multiplies with
 * vpmaddubsw, whose int16 pair sums saturate (an input near 255 against two weights near
 * 127), and its velocities differ from the exact ones by up to hundreds on such a network.
 * The elementwise tail runs on AVX-512 beside AMX (every AMX processor has it) and VNNI,
 * on AVX2 with FMA beside AVX2, and in plain C (fmaf) otherwise: the same correctly
 * rounded operations in the same order.
 *
 * Plain C99, the CPython API and the compiler's intrinsics (target attributes, so the file
 * builds for any x86-64 and elsewhere without the AMX path); no numpy headers.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <pthread.h>
#include <sched.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../pipeline/row_helper.h"

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 11
#define HAVE_X86_PATHS 1
#include <cpuid.h>
#include <immintrin.h>
#include <sys/syscall.h>
#include <unistd.h>
#else
#define HAVE_X86_PATHS 0
#endif

/* AMX tiles: 16 rows of 64 bytes; a block of the product is 32 rows x 32 columns. */
#define K_BLOCK 64
#define N_TILE 16
#define M_BLOCK 32
#define N_BLOCK 32

/* MLAS's logistic (onnxruntime/core/mlas/lib/logistic.cpp, MlasLogisticConstants). */
static const float LOGISTIC_LOWER = -18.0f, LOGISTIC_UPPER = 18.0f;
static const float ALPHA_9 = 4.37031012579801e-11f, ALPHA_7 = 1.15627324459942e-07f,
                   ALPHA_5 = 6.08574864600143e-05f, ALPHA_3 = 8.51377133304701e-03f,
                   ALPHA_1 = 2.48287947061529e-01f;
static const float BETA_10 = 6.10247389755681e-13f, BETA_8 = 5.76102136993427e-09f,
                   BETA_6 = 6.29106785017040e-06f, BETA_4 = 1.70198817374094e-03f,
                   BETA_2 = 1.16817656904453e-01f, BETA_0 = 9.93151921023180e-01f;

typedef struct {
    Py_ssize_t k, n;       /* the layer's input and output widths */
    Py_ssize_t k_pad;      /* k rounded up to K_BLOCK: the quantised input's row stride */
    Py_ssize_t n_pad;      /* n rounded up to N_BLOCK */
    int silu;              /* 1: SiLU after the affine map; 0: none (the last layer) */
    Py_buffer weight;      /* int8 (k, n), row-major */
    int8_t *packed;        /* (k_pad / 64, n_pad / 16, 16, 64): AMX's B tiles, zero-padded,
                            * 64-byte aligned (a tile row across two cache lines halves the
                            * product's speed) */
    int16_t *pairs;        /* (n_pad / C, k_pad / 2, C, 2), C = AVX2_COLUMNS: W widened for
                            * vpmaddwd, pairs of rows side by side, zero-padded, 64-byte
                            * aligned; NULL without AVX2 */
    Py_buffer column_sum;  /* int32 (n,): sum over k of weight */
    Py_buffer weight_scale;/* float32 (n,) */
    Py_buffer bias;        /* float32 (n,) */
} Layer;

typedef struct {
    Py_ssize_t count;
    Py_ssize_t widest;     /* the largest n */
    Py_ssize_t widest_k;   /* the largest k_pad */
    Layer layers[];
} Network;

/* The running sums of the AVX2 peak probe (peak_avx2): with the weights, 13 of AVX2's 16
 * vector registers. */
#define PEAK_SUMS 12

/* The product's paths, best first where the processor has them. */
enum { KERNEL_PLAIN = 0, KERNEL_AVX2 = 1, KERNEL_AMX = 2, KERNEL_VNNI = 3 };

/* ------------------------------------------------------------------ plain C, any CPU */

static float logistic(float x) {
    float v = fminf(LOGISTIC_UPPER, fmaxf(LOGISTIC_LOWER, x));
    float v2 = v * v;
    float p = fmaf(v2, ALPHA_9, ALPHA_7);
    p = fmaf(v2, p, ALPHA_5);
    p = fmaf(v2, p, ALPHA_3);
    p = fmaf(v2, p, ALPHA_1);
    float q = fmaf(v2, BETA_10, BETA_8);
    q = fmaf(v2, q, BETA_6);
    q = fmaf(v2, q, BETA_4);
    q = fmaf(v2, q, BETA_2);
    q = fmaf(v2, q, BETA_0);
    float y = (v * p) / q + 0.5f;
    return y > 0.0f ? y : 0.0f;
}

/* onnxruntime's GetQuantizationParameter for uint8: the range widened to hold 0. */
static void quantisation(float low, float high, float *scale, int32_t *zero_point) {
    low = low < 0.0f ? low : 0.0f;
    high = high > 0.0f ? high : 0.0f;
    float s = high == low ? 1.0f : (high - low) / 255.0f;
    float z = 0.0f - low / s;
    z = z < 255.0f ? z : 255.0f;
    z = z > 0.0f ? z : 0.0f;
    *scale = s;
    *zero_point = (int32_t)nearbyintf(z);
}

static void min_max_plain(const float *x, size_t count, float *low, float *high) {
    float lo = x[0], hi = x[0];
    for (size_t i = 1; i < count; ++i) {
        lo = x[i] < lo ? x[i] : lo;
        hi = x[i] > hi ? x[i] : hi;
    }
    *low = lo, *high = hi;
}

/* MlasQuantizeLinear: x / scale clamped to [-zp, 255 - zp], rounded to even, plus zp. */
static void quantise_plain(const float *x, Py_ssize_t M, Py_ssize_t k, Py_ssize_t k_pad,
                           float scale, int32_t zero_point, uint8_t *a) {
    float lo = (float)(0 - zero_point), hi = (float)(255 - zero_point);
    for (Py_ssize_t i = 0; i < M; ++i)
        for (Py_ssize_t j = 0; j < k; ++j) {
            float v = x[i * k + j] / scale;
            v = v > lo ? v : lo;
            v = v < hi ? v : hi;
            a[i * k_pad + j] = (uint8_t)((int32_t)nearbyintf(v) + zero_point);
        }
}

/* One layer on plain C: out (M, n) from the quantised input a (M, k_pad); low and high
 * take the outputs' least and greatest value (the next layer's range). */
static void layer_plain(const Layer *L, const uint8_t *a, Py_ssize_t M, float scale,
                        int32_t zero_point, float *out, int32_t *row, float *low, float *high) {
    const int8_t *W = L->weight.buf;
    const int32_t *colsum = L->column_sum.buf;
    const float *w_scale = L->weight_scale.buf, *bias = L->bias.buf;
    Py_ssize_t k = L->k, n = L->n;
    float lo = INFINITY, hi = -INFINITY;
    for (Py_ssize_t i = 0; i < M; ++i) {
        memset(row, 0, (size_t)n * sizeof *row);
        for (Py_ssize_t kk = 0; kk < k; ++kk) {
            int32_t aik = a[i * L->k_pad + kk];
            const int8_t *w = W + kk * n;
            for (Py_ssize_t j = 0; j < n; ++j) row[j] += aik * (int32_t)w[j];
        }
        for (Py_ssize_t j = 0; j < n; ++j) {
            float multiplier = scale * w_scale[j];
            float y = (float)(row[j] - zero_point * colsum[j]) * multiplier + bias[j];
            y = L->silu ? y * logistic(y) : y;
            out[i * n + j] = y;
            lo = y < lo ? y : lo;
            hi = y > hi ? y : hi;
        }
    }
    *low = lo, *high = hi;
}

/* ---------------------------------------------------------------- AVX2 and FMA path */

#if HAVE_X86_PATHS

static int avx2_state = -1;

/* 1 when this processor (and the system's saving of its registers) has AVX2 and FMA. */
static int avx2_usable(void) {
    if (avx2_state >= 0) return avx2_state;
    __builtin_cpu_init();
    avx2_state = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    return avx2_state;
}

/* A block of the product: R rows (at most AVX2_ROWS) by AVX2_COLUMNS columns, in
 * AVX2_VECTORS vectors of 8 int32 sums each. */
#define AVX2_ROWS 4
#define AVX2_VECTORS 2
#define AVX2_COLUMNS (8 * AVX2_VECTORS)
#define AVX2_CHUNK 32
_Static_assert(N_BLOCK % AVX2_COLUMNS == 0, "a layer's n_pad holds whole blocks");

__attribute__((target("avx2,fma"))) static inline __m256 logistic_avx2(__m256 x) {
    __m256 v = _mm256_min_ps(_mm256_max_ps(x, _mm256_set1_ps(LOGISTIC_LOWER)),
                             _mm256_set1_ps(LOGISTIC_UPPER));
    __m256 v2 = _mm256_mul_ps(v, v);
    __m256 p = _mm256_fmadd_ps(v2, _mm256_set1_ps(ALPHA_9), _mm256_set1_ps(ALPHA_7));
    p = _mm256_fmadd_ps(v2, p, _mm256_set1_ps(ALPHA_5));
    p = _mm256_fmadd_ps(v2, p, _mm256_set1_ps(ALPHA_3));
    p = _mm256_fmadd_ps(v2, p, _mm256_set1_ps(ALPHA_1));
    __m256 q = _mm256_fmadd_ps(v2, _mm256_set1_ps(BETA_10), _mm256_set1_ps(BETA_8));
    q = _mm256_fmadd_ps(v2, q, _mm256_set1_ps(BETA_6));
    q = _mm256_fmadd_ps(v2, q, _mm256_set1_ps(BETA_4));
    q = _mm256_fmadd_ps(v2, q, _mm256_set1_ps(BETA_2));
    q = _mm256_fmadd_ps(v2, q, _mm256_set1_ps(BETA_0));
    __m256 y = _mm256_add_ps(_mm256_div_ps(_mm256_mul_ps(v, p), q), _mm256_set1_ps(0.5f));
    return _mm256_max_ps(y, _mm256_setzero_ps());
}

/* The least of lo's lanes and the greatest of hi's. */
__attribute__((target("avx2,fma"))) static void reduce_avx2(__m256 lo, __m256 hi, float *low,
                                                           float *high) {
    float l[8], h[8];
    _mm256_storeu_ps(l, lo), _mm256_storeu_ps(h, hi);
    float a = l[0], b = h[0];
    for (int j = 1; j < 8; ++j) a = l[j] < a ? l[j] : a, b = h[j] > b ? h[j] : b;
    *low = a, *high = b;
}

__attribute__((target("avx2,fma"))) static void min_max_avx2(const float *x, size_t count,
                                                            float *low, float *high) {
    __m256 lo = _mm256_set1_ps(x[0]), hi = lo;
    size_t i = 0;
    for (; i + 8 <= count; i += 8) {
        __m256 v = _mm256_loadu_ps(x + i);
        lo = _mm256_min_ps(lo, v), hi = _mm256_max_ps(hi, v);
    }
    float a, b;
    reduce_avx2(lo, hi, &a, &b);
    for (; i < count; ++i) a = x[i] < a ? x[i] : a, b = x[i] > b ? x[i] : b;
    *low = a, *high = b;
}

/* quantise_plain's arithmetic (a true division, rounding to even) into int16 (M, k_pad). */
__attribute__((target("avx2,fma"))) static void quantise_avx2(const float *x, Py_ssize_t M,
                                                             Py_ssize_t k, Py_ssize_t k_pad,
                                                             float scale, int32_t zero_point,
                                                             int16_t *a) {
    __m256 s = _mm256_set1_ps(scale);
    float flo = (float)(0 - zero_point), fhi = (float)(255 - zero_point);
    __m256 lo = _mm256_set1_ps(flo), hi = _mm256_set1_ps(fhi);
    __m256i z = _mm256_set1_epi32(zero_point);
    for (Py_ssize_t i = 0; i < M; ++i) {
        const float *xi = x + i * k;
        int16_t *ai = a + i * k_pad;
        Py_ssize_t j = 0;
        for (; j + 8 <= k; j += 8) {
            __m256 v = _mm256_div_ps(_mm256_loadu_ps(xi + j), s);
            v = _mm256_min_ps(_mm256_max_ps(v, lo), hi);
            v = _mm256_round_ps(v, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
            __m256i q = _mm256_add_epi32(_mm256_cvtps_epi32(v), z);
            __m256i packed = _mm256_permute4x64_epi64(_mm256_packs_epi32(q, q), 0x08);
            _mm_storeu_si128((__m128i *)(ai + j), _mm256_castsi256_si128(packed));
        }
        for (; j < k; ++j) {
            float v = xi[j] / scale;
            v = v > flo ? v : flo;
            v = v < fhi ? v : fhi;
            ai[j] = (int16_t)((int32_t)nearbyintf(v) + zero_point);
        }
        for (; j < k_pad; ++j) ai[j] = 0;
    }
}

/* Rows [i, i + R) by columns [j0, j0 + AVX2_COLUMNS) of one layer: the exact product on
 * vpmaddwd, then the tail of layer_plain in its order (mul, add; SiLU's fused
 * multiply-adds). Inlined with R constant, so the sums stay in registers. */
__attribute__((target("avx2,fma"), always_inline)) static inline void block_avx2(
    const Layer *L, const int16_t *a, Py_ssize_t i, int R, Py_ssize_t j0, float scale,
    int32_t zero_point, float *out, __m256 *low, __m256 *high) {
    Py_ssize_t k_pad = L->k_pad, n = L->n;
    const int16_t *w = L->pairs + j0 * k_pad;  /* this block's (k_pad / 2, AVX2_COLUMNS, 2) */
    __m256i acc[AVX2_ROWS][AVX2_VECTORS];
#pragma GCC unroll 8
    for (int r = 0; r < R; ++r)
#pragma GCC unroll 8
        for (int h = 0; h < AVX2_VECTORS; ++h) acc[r][h] = _mm256_setzero_si256();
#pragma GCC unroll 2
    for (Py_ssize_t p = 0; p < k_pad / 2; ++p) {
        __m256i wv[AVX2_VECTORS];
#pragma GCC unroll 8
        for (int h = 0; h < AVX2_VECTORS; ++h)
            wv[h] = _mm256_load_si256((const __m256i *)(w + (p * AVX2_VECTORS + h) * 16));
#pragma GCC unroll 8
        for (int r = 0; r < R; ++r) {
            int32_t pair;
            memcpy(&pair, a + (i + r) * k_pad + 2 * p, sizeof pair);
            __m256i x = _mm256_set1_epi32(pair);
#pragma GCC unroll 8
            for (int h = 0; h < AVX2_VECTORS; ++h)
                acc[r][h] = _mm256_add_epi32(acc[r][h], _mm256_madd_epi16(x, wv[h]));
        }
    }
    const int32_t *colsum = L->column_sum.buf;
    const float *w_scale = L->weight_scale.buf, *bias = L->bias.buf;
    __m256i z = _mm256_set1_epi32(zero_point);
    __m256 s = _mm256_set1_ps(scale);
    for (int h = 0; h < AVX2_VECTORS; ++h) {
        Py_ssize_t j = j0 + 8 * h;
        if (j >= n) break;
        int whole = n - j >= 8;
        int32_t cs[8] = {0};
        float ws[8] = {0}, bs[8] = {0};
        memcpy(cs, colsum + j, (size_t)(whole ? 8 : n - j) * sizeof *cs);
        memcpy(ws, w_scale + j, (size_t)(whole ? 8 : n - j) * sizeof *ws);
        memcpy(bs, bias + j, (size_t)(whole ? 8 : n - j) * sizeof *bs);
        __m256i correction = _mm256_mullo_epi32(z, _mm256_loadu_si256((const __m256i *)cs));
        __m256 multiplier = _mm256_mul_ps(s, _mm256_loadu_ps(ws));
        __m256 b = _mm256_loadu_ps(bs);
#pragma GCC unroll 8
        for (int r = 0; r < R; ++r) {
            __m256 y = _mm256_cvtepi32_ps(_mm256_sub_epi32(acc[r][h], correction));
            y = _mm256_add_ps(_mm256_mul_ps(y, multiplier), b);
            if (L->silu) y = _mm256_mul_ps(y, logistic_avx2(y));
            float *o = out + (i + r) * n + j;
            if (whole) {
                _mm256_storeu_ps(o, y);
                *low = _mm256_min_ps(*low, y), *high = _mm256_max_ps(*high, y);
            } else {
                float part[8];
                _mm256_storeu_ps(part, y);
                for (Py_ssize_t c = 0; c < n - j; ++c) o[c] = part[c];
                for (Py_ssize_t c = n - j; c < 8; ++c) part[c] = part[0];  /* past n: one of n's */
                y = _mm256_loadu_ps(part);
                *low = _mm256_min_ps(*low, y), *high = _mm256_max_ps(*high, y);
            }
        }
    }
}

/* One layer on AVX2: a (M, k_pad) int16 -> out (M, n) float32, AVX2_CHUNK rows at a time:
 * each block of AVX2_COLUMNS columns of the weights (k_pad * 64 bytes: in the first-level
 * cache) against the chunk's rows in turn. The chunk keeps a thread's working set (its
 * rows' input and output, the widened weights, 512 kB for a 512-wide layer) within its
 * core's second-level cache: a whole 250-row share at once does not fit, and a call of 500
 * rows on two threads then takes 8.1 ms instead of 6.0-7.0 (2-core AMD EPYC; CHANGELOG). */
__attribute__((target("avx2,fma"))) static void layer_avx2(const Layer *L, const int16_t *a,
                                                          Py_ssize_t M, float scale,
                                                          int32_t zero_point, float *out,
                                                          float *low, float *high) {
    __m256 lo = _mm256_set1_ps(INFINITY), hi = _mm256_set1_ps(-INFINITY);
    for (Py_ssize_t i0 = 0; i0 < M; i0 += AVX2_CHUNK) {
        Py_ssize_t i1 = M - i0 < AVX2_CHUNK ? M : i0 + AVX2_CHUNK;
        for (Py_ssize_t j0 = 0; j0 < L->n; j0 += AVX2_COLUMNS) {
            Py_ssize_t i = i0;
            for (; i + AVX2_ROWS <= i1; i += AVX2_ROWS)
                block_avx2(L, a, i, AVX2_ROWS, j0, scale, zero_point, out, &lo, &hi);
            for (; i < i1; ++i) block_avx2(L, a, i, 1, j0, scale, zero_point, out, &lo, &hi);
        }
    }
    reduce_avx2(lo, hi, low, high);
}

/* W (k, n) int8 into vpmaddwd's pairs (n_pad / C, k_pad / 2, C, 2), C = AVX2_COLUMNS:
 * block jb, pair p, column c holds W[2p, C jb + c] and W[2p + 1, C jb + c], zero past k
 * and n. */
static void pack_pairs(const int8_t *W, Py_ssize_t k, Py_ssize_t n, Py_ssize_t k_pad,
                       Py_ssize_t n_pad, int16_t *P) {
    memset(P, 0, (size_t)(k_pad * n_pad) * sizeof *P);
    for (Py_ssize_t kk = 0; kk < k; ++kk)
        for (Py_ssize_t j = 0; j < n; ++j) {
            Py_ssize_t jb = j / AVX2_COLUMNS, c = j % AVX2_COLUMNS, p = kk / 2;
            P[(jb * (k_pad / 2) + p) * 2 * AVX2_COLUMNS + c * 2 + kk % 2] = W[kk * n + j];
        }
}

/* The AVX2 product's own peak: PEAK_SUMS running sums, each adding a vpmaddwd of its own
 * activation pairs (read from memory, as the layers broadcast theirs) against one vector of
 * weight pairs, round after round, with nothing else in the loop (no quantisation, no
 * rescaling). The sums stay in registers (PEAK_SUMS + 1 of the 16); an empty asm each
 * round, which may change the weights and the activations' pointer, keeps the compiler
 * from hoisting the products or the loads out of the loop. Returns the sum of every lane
 * of every running sum: rounds times the sum of each activation vector's dot product with
 * the weights, which the caller checks, so the rounds were run. */
#define PEAK_STEP(a, s)                                                                    \
    a = _mm256_add_epi32(                                                                  \
        a, _mm256_madd_epi16(_mm256_loadu_si256((const __m256i *)(xr + 16 * s)), wv))
__attribute__((target("avx2,fma"))) static int64_t peak_avx2(const int16_t *x, const int16_t *w,
                                                             long rounds) {
    __m256i wv = _mm256_loadu_si256((const __m256i *)w);
    __m256i a0 = _mm256_setzero_si256(), a1 = a0, a2 = a0, a3 = a0, a4 = a0, a5 = a0, a6 = a0,
            a7 = a0, a8 = a0, a9 = a0, a10 = a0, a11 = a0;
    const int16_t *xr = x;
    for (long r = 0; r < rounds; ++r) {
        __asm__ volatile("" : "+x"(wv), "+r"(xr));
        PEAK_STEP(a0, 0), PEAK_STEP(a1, 1), PEAK_STEP(a2, 2), PEAK_STEP(a3, 3);
        PEAK_STEP(a4, 4), PEAK_STEP(a5, 5), PEAK_STEP(a6, 6), PEAK_STEP(a7, 7);
        PEAK_STEP(a8, 8), PEAK_STEP(a9, 9), PEAK_STEP(a10, 10), PEAK_STEP(a11, 11);
    }
    __m256i sums[PEAK_SUMS] = {a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11};
    int64_t total = 0;
    for (int s = 0; s < PEAK_SUMS; ++s) {
        int32_t lanes[8];
        _mm256_storeu_si256((__m256i *)lanes, sums[s]);
        for (int l = 0; l < 8; ++l) total += lanes[l];
    }
    return total;
}
#undef PEAK_STEP

#else
static int avx2_usable(void) { return 0; }
static int64_t peak_avx2(const int16_t *x, const int16_t *w, long rounds) {
    return 0;  /* never called: avx2_usable() is 0 */
}
#endif

/* ------------------------------------------------------------- AMX and AVX-512 path */

#if HAVE_X86_PATHS

#define ARCH_REQ_XCOMP_PERM 0x1023
#define XFEATURE_XTILEDATA 18

typedef struct {
    uint8_t palette_id, start_row, reserved[14];
    uint16_t colsb[16];
    uint8_t rows[16];
} __attribute__((packed)) TileConfig;

/* 1 when this process may use AMX-INT8 tiles and AVX-512F (asks the kernel once). */
static int amx_state = -1;

static int amx_usable(void) {
    if (amx_state >= 0) return amx_state;
    unsigned a, b, c, d;
    int ok = __get_cpuid_count(7, 0, &a, &b, &c, &d) && (d >> 24 & 1) && (d >> 25 & 1) &&
             (b >> 16 & 1);
    if (ok) ok = syscall(SYS_arch_prctl, ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA) == 0;
    amx_state = ok;
    return ok;
}

__attribute__((target("avx512f"))) static void min_max_avx512(const float *x, size_t count,
                                                              float *low, float *high) {
    __m512 lo = _mm512_set1_ps(x[0]), hi = lo;
    size_t i = 0;
    for (; i + 16 <= count; i += 16) {
        __m512 v = _mm512_loadu_ps(x + i);
        lo = _mm512_min_ps(lo, v), hi = _mm512_max_ps(hi, v);
    }
    if (i < count) {
        __mmask16 m = (__mmask16)((1u << (count - i)) - 1u);
        __m512 v = _mm512_maskz_loadu_ps(m, x + i);
        lo = _mm512_mask_min_ps(lo, m, lo, v), hi = _mm512_mask_max_ps(hi, m, hi, v);
    }
    *low = _mm512_reduce_min_ps(lo), *high = _mm512_reduce_max_ps(hi);
}

/* MlasQuantizeLinear's x / scale, rounded to even, without a division per value: x times
 * the reciprocal is within 2^-22 relative of the correctly rounded quotient, 6.1e-5 at
 * the range's 255, so both round to the same integer unless the product lies within
 * 1e-4 of a half-integer; a vector with such a lane is divided (about one in 300). */
__attribute__((target("avx512f"))) static void quantise_avx512(const float *x, Py_ssize_t M,
                                                               Py_ssize_t k, Py_ssize_t k_pad,
                                                               float scale, int32_t zero_point,
                                                               uint8_t *a) {
    __m512 s = _mm512_set1_ps(scale), r = _mm512_set1_ps(1.0f / scale);
    __m512 near_tie = _mm512_set1_ps(0.5f - 1e-4f);
    __m512 lo = _mm512_set1_ps((float)(0 - zero_point)), hi = _mm512_set1_ps((float)(255 - zero_point));
    __m512i z = _mm512_set1_epi32(zero_point);
    for (Py_ssize_t i = 0; i < M; ++i) {
        const float *xi = x + i * k;
        uint8_t *ai = a + i * k_pad;
        for (Py_ssize_t j = 0; j < k; j += 16) {
            __mmask16 m = k - j >= 16 ? (__mmask16)0xFFFF : (__mmask16)((1u << (k - j)) - 1u);
            __m512 value = _mm512_maskz_loadu_ps(m, xi + j);
            __m512 v = _mm512_mul_ps(value, r);
            __m512 off = _mm512_abs_ps(_mm512_sub_ps(v, _mm512_roundscale_ps(v, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC)));
            if (_mm512_mask_cmp_ps_mask(m, off, near_tie, _CMP_GE_OQ)) v = _mm512_div_ps(value, s);
            v = _mm512_min_ps(_mm512_max_ps(v, lo), hi);
            __m512i q = _mm512_add_epi32(_mm512_cvtps_epi32(v), z);
            _mm512_mask_cvtepi32_storeu_epi8(ai + j, m, q);
        }
    }
}

__attribute__((target("avx512f"))) static __m512 logistic_avx512(__m512 x) {
    __m512 v = _mm512_min_ps(_mm512_set1_ps(LOGISTIC_UPPER),
                             _mm512_max_ps(_mm512_set1_ps(LOGISTIC_LOWER), x));
    __m512 v2 = _mm512_mul_ps(v, v);
    __m512 p = _mm512_fmadd_ps(v2, _mm512_set1_ps(ALPHA_9), _mm512_set1_ps(ALPHA_7));
    p = _mm512_fmadd_ps(v2, p, _mm512_set1_ps(ALPHA_5));
    p = _mm512_fmadd_ps(v2, p, _mm512_set1_ps(ALPHA_3));
    p = _mm512_fmadd_ps(v2, p, _mm512_set1_ps(ALPHA_1));
    __m512 q = _mm512_fmadd_ps(v2, _mm512_set1_ps(BETA_10), _mm512_set1_ps(BETA_8));
    q = _mm512_fmadd_ps(v2, q, _mm512_set1_ps(BETA_6));
    q = _mm512_fmadd_ps(v2, q, _mm512_set1_ps(BETA_4));
    q = _mm512_fmadd_ps(v2, q, _mm512_set1_ps(BETA_2));
    q = _mm512_fmadd_ps(v2, q, _mm512_set1_ps(BETA_0));
    __m512 y = _mm512_add_ps(_mm512_div_ps(_mm512_mul_ps(v, p), q), _mm512_set1_ps(0.5f));
    return _mm512_max_ps(_mm512_setzero_ps(), y);
}

/* The tail of rows [r0, rows) of one block: acc (32, N_BLOCK) int32 for the layer's rows
 * i0.. and columns j0... */
__attribute__((target("avx512f"))) static void tail_avx512(const Layer *L, const int32_t *acc,
                                                           Py_ssize_t r0, Py_ssize_t rows,
                                                           Py_ssize_t i0,
                                                           Py_ssize_t j0, float scale,
                                                           int32_t zero_point, float *out,
                                                           __m512 *low, __m512 *high) {
    const int32_t *colsum = L->column_sum.buf;
    const float *w_scale = L->weight_scale.buf, *bias = L->bias.buf;
    Py_ssize_t n = L->n;
    __m512i z = _mm512_set1_epi32(zero_point);
    __m512 s = _mm512_set1_ps(scale);
    for (Py_ssize_t jj = 0; jj < N_BLOCK && j0 + jj < n; jj += N_TILE) {
        Py_ssize_t j = j0 + jj;
        __mmask16 m = n - j >= 16 ? (__mmask16)0xFFFF : (__mmask16)((1u << (n - j)) - 1u);
        __m512i correction = _mm512_mullo_epi32(z, _mm512_maskz_loadu_epi32(m, colsum + j));
        __m512 multiplier = _mm512_mul_ps(s, _mm512_maskz_loadu_ps(m, w_scale + j));
        __m512 b = _mm512_maskz_loadu_ps(m, bias + j);
        for (Py_ssize_t r = r0; r < rows; ++r) {
            __m512i a = _mm512_loadu_si512(acc + r * N_BLOCK + jj);
            __m512 y = _mm512_cvtepi32_ps(_mm512_sub_epi32(a, correction));
            y = _mm512_add_ps(_mm512_mul_ps(y, multiplier), b);
            if (L->silu) y = _mm512_mul_ps(y, logistic_avx512(y));
            _mm512_mask_storeu_ps(out + (i0 + r) * n + j, m, y);
            *low = _mm512_mask_min_ps(*low, m, *low, y);
            *high = _mm512_mask_max_ps(*high, m, *high, y);
        }
    }
}

/* One layer on AMX: a (M_pad, k_pad) uint8 -> out (M, n) float32. The products of a
 * 32 x 32 block are issued to the tiles, then the vector units do the tail of the block
 * before, then the tiles store this one: a block read straight after the tiles store it
 * stalls (tile stores do not forward to vector loads). */
__attribute__((target("amx-tile,amx-int8,avx512f"))) static void layer_amx(
    const Layer *L, const uint8_t *a, Py_ssize_t M, float scale, int32_t zero_point, float *out,
    float *low, float *high) {
    const int8_t *B = L->packed;
    Py_ssize_t k_pad = L->k_pad, n_tiles = L->n_pad / N_TILE, blocks_n = n_tiles / 2;
    int32_t acc[2][M_BLOCK * N_BLOCK] __attribute__((aligned(64)));
    __m512 lo = _mm512_set1_ps(INFINITY), hi = _mm512_set1_ps(-INFINITY);
    Py_ssize_t blocks = (M + M_BLOCK - 1) / M_BLOCK * blocks_n;
    for (Py_ssize_t block = 0; block <= blocks; ++block) {
        if (block < blocks) {
            Py_ssize_t i = block / blocks_n * M_BLOCK, t = block % blocks_n * 2;
            const uint8_t *a0 = a + i * k_pad, *a1 = a0 + 16 * k_pad;
            _tile_zero(0);
            _tile_zero(1);
            _tile_zero(2);
            _tile_zero(3);
            for (Py_ssize_t kb = 0; kb < k_pad / K_BLOCK; ++kb) {
                const int8_t *b0 = B + (kb * n_tiles + t) * 1024;
                _tile_loadd(4, a0 + kb * K_BLOCK, k_pad);
                _tile_loadd(5, a1 + kb * K_BLOCK, k_pad);
                _tile_loadd(6, b0, 64);
                _tile_loadd(7, b0 + 1024, 64);
                _tile_dpbusd(0, 4, 6);
                _tile_dpbusd(1, 4, 7);
                _tile_dpbusd(2, 5, 6);
                _tile_dpbusd(3, 5, 7);
            }
        }
        if (block > 0) {
            Py_ssize_t before = block - 1, i = before / blocks_n * M_BLOCK;
            Py_ssize_t rows = M - i < M_BLOCK ? M - i : M_BLOCK;
            tail_avx512(L, acc[before % 2], 0, rows, i, before % blocks_n * 2 * N_TILE, scale,
                        zero_point, out, &lo, &hi);
        }
        if (block < blocks) {
            int32_t *c = acc[block % 2];
            _tile_stored(0, c, N_BLOCK * 4);
            _tile_stored(1, c + 16, N_BLOCK * 4);
            _tile_stored(2, c + 16 * N_BLOCK, N_BLOCK * 4);
            _tile_stored(3, c + 16 * N_BLOCK + 16, N_BLOCK * 4);
        }
    }
    *low = _mm512_reduce_min_ps(lo), *high = _mm512_reduce_max_ps(hi);
}

/* Palette 1, every tile 16 rows of 64 bytes. Static storage: GCC 12 drops the stores to a
 * local configuration before ldtilecfg reads it (seen at -O2). */
static const TileConfig TILES = {
    .palette_id = 1,
    .colsb = {64, 64, 64, 64, 64, 64, 64, 64},
    .rows = {16, 16, 16, 16, 16, 16, 16, 16},
};

__attribute__((target("amx-tile"))) static void tiles_configure(void) { _tile_loadconfig(&TILES); }

__attribute__((target("amx-tile"))) static void tiles_release(void) { _tile_release(); }

/* ------------------------------------------------------------ AVX-512 VNNI path */

/* 1 when this processor (and the system's saving of its registers) has AVX-512F, BW and
 * VNNI: Intel from Cascade Lake, AMD from Zen 4. */
static int vnni_state = -1;

static int vnni_usable(void) {
    if (vnni_state >= 0) return vnni_state;
    __builtin_cpu_init();
    vnni_state = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                 __builtin_cpu_supports("avx512vnni");
    return vnni_state;
}

/* A block of the product on VNNI: R rows (at most VNNI_ROWS) by N_BLOCK columns, two
 * vectors of 16 int32 sums a row (2 R + 3 of the 32 vector registers). */
#define VNNI_ROWS 8

/* Rows [i, i + R) of the quantised input a (M, k_pad) uint8 against column tiles t and
 * t + 1 of the packed weights (AMX's B tiles, whose 64-byte rows are vpdpbusd's operand:
 * four consecutive k of one column per int32 lane), into rows [r0, r0 + R) of acc
 * (M_BLOCK, N_BLOCK). Inlined with R constant, so the sums stay in registers. */
__attribute__((target("avx512f,avx512bw,avx512vnni"), always_inline)) static inline void
block_vnni(const Layer *L, const uint8_t *a, Py_ssize_t i, int R, Py_ssize_t t, int32_t *acc,
           Py_ssize_t r0) {
    Py_ssize_t k_pad = L->k_pad, n_tiles = L->n_pad / N_TILE;
    __m512i sum[VNNI_ROWS][2];
#pragma GCC unroll 8
    for (int r = 0; r < R; ++r) sum[r][0] = sum[r][1] = _mm512_setzero_si512();
    for (Py_ssize_t kb = 0; kb < k_pad / K_BLOCK; ++kb) {
        const int8_t *b = L->packed + (kb * n_tiles + t) * 1024;
        const uint8_t *ak = a + i * k_pad + kb * K_BLOCK;
#pragma GCC unroll 2
        for (int q = 0; q < K_BLOCK / 4; ++q) {
            __m512i w0 = _mm512_load_si512((const void *)(b + q * 64));
            __m512i w1 = _mm512_load_si512((const void *)(b + 1024 + q * 64));
#pragma GCC unroll 8
            for (int r = 0; r < R; ++r) {
                int32_t quad;
                memcpy(&quad, ak + r * k_pad + 4 * q, sizeof quad);
                __m512i x = _mm512_set1_epi32(quad);
                sum[r][0] = _mm512_dpbusd_epi32(sum[r][0], x, w0);
                sum[r][1] = _mm512_dpbusd_epi32(sum[r][1], x, w1);
            }
        }
    }
#pragma GCC unroll 8
    for (int r = 0; r < R; ++r) {
        _mm512_store_si512((void *)(acc + (r0 + r) * N_BLOCK), sum[r][0]);
        _mm512_store_si512((void *)(acc + (r0 + r) * N_BLOCK + N_TILE), sum[r][1]);
    }
}

/* One layer on VNNI: a (M, k_pad) uint8 -> out (M, n) float32, a block of M_BLOCK rows by
 * N_BLOCK columns at a time (the block's weights, 16 kB of a 512-deep layer, and its rows'
 * input stay in the first-level cache), each block's tail by tail_avx512 as on AMX. */
__attribute__((target("avx512f,avx512bw,avx512vnni"))) static void layer_vnni(
    const Layer *L, const uint8_t *a, Py_ssize_t M, float scale, int32_t zero_point, float *out,
    float *low, float *high) {
    int32_t acc[M_BLOCK * N_BLOCK] __attribute__((aligned(64)));
    __m512 lo = _mm512_set1_ps(INFINITY), hi = _mm512_set1_ps(-INFINITY);
    for (Py_ssize_t i0 = 0; i0 < M; i0 += M_BLOCK) {
        Py_ssize_t rows = M - i0 < M_BLOCK ? M - i0 : M_BLOCK;
        for (Py_ssize_t t = 0; t < L->n_pad / N_TILE; t += 2) {
            Py_ssize_t r = 0;
            for (; r + VNNI_ROWS <= rows; r += VNNI_ROWS)
                block_vnni(L, a, i0 + r, VNNI_ROWS, t, acc, r);
            for (; r < rows; ++r) block_vnni(L, a, i0 + r, 1, t, acc, r);
            tail_avx512(L, acc, 0, rows, i0, t * N_TILE, scale, zero_point, out, &lo, &hi);
        }
    }
    *low = _mm512_reduce_min_ps(lo), *high = _mm512_reduce_max_ps(hi);
}

#else
static int amx_usable(void) { return 0; }
static int vnni_usable(void) { return 0; }
#endif

/* ------------------------------------------------------------------------ forward */

/* Scratch blocks kept between calls: a call's activations are about 4 kB a row, and a
 * block of that size freed to glibc goes back to the system (the service's mmap threshold),
 * so each call would otherwise fault its pages in again (about 4,500 faults a call of
 * 4,000 rows of 512). Up to SCRATCH_SLOTS blocks of at most `scratch_keep_bytes` each
 * stay, as many as flow calls run at once in the service (SMM_MAX_IN_FLIGHT's 2); a call
 * that needs more frees its own. keep_scratch sets the bound (the service's
 * SMM_FLOW_SCRATCH_BYTES); 6 MiB, about 1,300 rows of 512, until it is called. The
 * process holds at most SCRATCH_SLOTS times the bound for them. */
#define SCRATCH_SLOTS 2

static struct {
    void *block;
    size_t bytes;
} scratch_slots[SCRATCH_SLOTS];
static size_t scratch_keep_bytes = (size_t)6 << 20;
static PyThread_type_lock scratch_lock;

static void *scratch_take(size_t bytes, size_t *held) {
    void *block = NULL;
    size_t size = 0;
    PyThread_acquire_lock(scratch_lock, WAIT_LOCK);
    for (int s = 0; s < SCRATCH_SLOTS && block == NULL; ++s)
        if (scratch_slots[s].block != NULL) {
            block = scratch_slots[s].block, size = scratch_slots[s].bytes;
            scratch_slots[s].block = NULL, scratch_slots[s].bytes = 0;
        }
    PyThread_release_lock(scratch_lock);
    if (block != NULL && size < bytes) free(block), block = NULL;
    if (block == NULL) block = malloc(bytes), size = bytes;
    *held = size;
    return block;
}

static void scratch_give(void *block, size_t bytes) {
    if (block == NULL) return;
    PyThread_acquire_lock(scratch_lock, WAIT_LOCK);
    if (bytes <= scratch_keep_bytes)
        for (int s = 0; s < SCRATCH_SLOTS && block != NULL; ++s)
            if (scratch_slots[s].block == NULL)
                scratch_slots[s].block = block, scratch_slots[s].bytes = bytes, block = NULL;
    PyThread_release_lock(scratch_lock);
    free(block);
}

/* A call's rows on one or two threads. Every layer needs the range of its whole input
 * before quantising any row of it, so the threads meet once a layer: each takes a share
 * of the rows (whole 32-row blocks), finds its share's range while it writes the layer's
 * output, and after the meeting both combine the shares' ranges alike. A row's velocity
 * is the same on one thread and on two (min and max do not depend on the order). */
#define MAX_LAYERS 64
#define MAX_THREADS 2

typedef struct {
    const Network *net;
    const float *x;
    float *y;
    Py_ssize_t M;
    int kernel, threads;  /* kernel: KERNEL_AMX, KERNEL_VNNI, KERNEL_AVX2 or KERNEL_PLAIN */
    uint8_t *a;           /* the quantised input: uint8 (M_pad, k_pad), int16 on AVX2 */
    float *buffers[2];
    int32_t *rows[MAX_THREADS];
    float low[MAX_LAYERS][MAX_THREADS], high[MAX_LAYERS][MAX_THREADS];
    int arrived, generation;
} Call;

/* Both threads past this point before either goes on (spinning: a layer takes tens of
 * microseconds, a sleep and a wake-up about as long). */
static void meet(Call *call) {
    if (call->threads == 1) return;
    int generation = __atomic_load_n(&call->generation, __ATOMIC_ACQUIRE);
    if (__atomic_add_fetch(&call->arrived, 1, __ATOMIC_ACQ_REL) == call->threads) {
        __atomic_store_n(&call->arrived, 0, __ATOMIC_RELAXED);
        __atomic_store_n(&call->generation, generation + 1, __ATOMIC_RELEASE);
        return;
    }
    for (long spins = 0; __atomic_load_n(&call->generation, __ATOMIC_ACQUIRE) == generation;
         ++spins)
        if (spins > 4096) sched_yield();
}

static void call_rows(Call *call, int share) {
    const Network *net = call->net;
    Py_ssize_t M = call->M, split = (M / 2 + M_BLOCK - 1) / M_BLOCK * M_BLOCK;
    Py_ssize_t i0 = call->threads == 1 || share == 0 ? 0 : split;
    Py_ssize_t i1 = call->threads == 1 || share == 1 ? M : split;
    Py_ssize_t count = i1 - i0, k0 = net->layers[0].k;
#if HAVE_X86_PATHS
    if (call->kernel == KERNEL_AMX || call->kernel == KERNEL_VNNI) {
        if (call->kernel == KERNEL_AMX) tiles_configure();
        min_max_avx512(call->x + i0 * k0, (size_t)(count * k0), &call->low[0][share],
                       &call->high[0][share]);
    } else if (call->kernel == KERNEL_AVX2)
        min_max_avx2(call->x + i0 * k0, (size_t)(count * k0), &call->low[0][share],
                     &call->high[0][share]);
    else
#endif
        min_max_plain(call->x + i0 * k0, (size_t)(count * k0), &call->low[0][share],
                      &call->high[0][share]);
    const float *input = call->x;
    for (Py_ssize_t l = 0; l < net->count; ++l) {
        const Layer *L = &net->layers[l];
        float *out = l == net->count - 1 ? call->y : call->buffers[l % 2];
        meet(call);
        float low = call->low[l][0], high = call->high[l][0], scale;
        for (int t = 1; t < call->threads; ++t) {
            low = call->low[l][t] < low ? call->low[l][t] : low;
            high = call->high[l][t] > high ? call->high[l][t] : high;
        }
        int32_t zero_point;
        quantisation(low, high, &scale, &zero_point);
        const float *x = input + i0 * L->k;
        uint8_t *a = call->a + i0 * L->k_pad;
        float *o = out + i0 * L->n, *lo = &call->low[l + 1][share], *hi = &call->high[l + 1][share];
#if HAVE_X86_PATHS
        if (call->kernel == KERNEL_AMX || call->kernel == KERNEL_VNNI) {
            quantise_avx512(x, count, L->k, L->k_pad, scale, zero_point, a);
            (call->kernel == KERNEL_AMX ? layer_amx : layer_vnni)(L, a, count, scale,
                                                                  zero_point, o, lo, hi);
        } else if (call->kernel == KERNEL_AVX2) {
            int16_t *a16 = (int16_t *)call->a + i0 * L->k_pad;
            quantise_avx2(x, count, L->k, L->k_pad, scale, zero_point, a16);
            layer_avx2(L, a16, count, scale, zero_point, o, lo, hi);
        } else
#endif
        {
            quantise_plain(x, count, L->k, L->k_pad, scale, zero_point, a);
            layer_plain(L, a, count, scale, zero_point, o, call->rows[share], lo, hi);
        }
        input = out;
    }
#if HAVE_X86_PATHS
    if (call->kernel == KERNEL_AMX) tiles_release();
#endif
}

/* The second share on the row helper (row_helper.h): a persistent thread, hot between a
 * sampler's calls, where a thread made per call cost its start on a core that had gone
 * idle. */
static void second_share(void *call, Py_ssize_t start, Py_ssize_t stop, int on_helper) {
    (void)start, (void)stop, (void)on_helper;
    call_rows(call, 1);
}

/* x (M, k of the first layer) -> y (M, n of the last) on `threads` threads (1 or 2; 1 for
 * fewer than two blocks of rows); 0, or -1 when out of memory. */
static int forward(const Network *net, const float *x, Py_ssize_t M, int kernel, int threads,
                   float *y) {
    Py_ssize_t M_pad = (M + M_BLOCK - 1) / M_BLOCK * M_BLOCK;
    threads = threads > 1 && M > M_BLOCK ? 2 : 1;
    size_t a_width = kernel == KERNEL_AVX2 ? sizeof(int16_t) : sizeof(uint8_t);
    size_t a_bytes = (size_t)(M_pad * net->widest_k) * a_width;
    size_t act_bytes = (size_t)(M * net->widest) * 4;
    size_t row_bytes = (size_t)net->widest * 4, held;
    size_t bytes = a_bytes + 2 * act_bytes + 2 * row_bytes + 5 * 64;
    char *block = scratch_take(bytes, &held);
    if (block == NULL) return -1;
    Call *call = PyMem_RawCalloc(1, sizeof(Call));
    if (call == NULL) {
        scratch_give(block, held);
        return -1;
    }
    uintptr_t at = ((uintptr_t)block + 63) & ~(uintptr_t)63;
    size_t sizes[5] = {a_bytes, act_bytes, act_bytes, row_bytes, row_bytes};
    void *parts[5];
    for (int p = 0; p < 5; ++p) parts[p] = (void *)at, at = (at + sizes[p] + 63) & ~(uintptr_t)63;
    /* AMX multiplies whole 32-row blocks: the rows of `a` past M hold whatever the block
     * held (integers, so nothing can trap), and their products are never stored. */
    *call = (Call){.net = net, .x = x, .y = y, .M = M, .kernel = kernel, .threads = threads,
                   .a = parts[0], .buffers = {parts[1], parts[2]}, .rows = {parts[3], parts[4]}};
    if (threads == 2 && !row_helper_claim())
        call->threads = 1; /* the helper busy with another call, or none to be had: all here */
    if (call->threads == 2) row_helper_post(second_share, call, 1);
    call_rows(call, 0);
    if (call->threads == 2) row_helper_finish();
    PyMem_RawFree(call);
    scratch_give(block, held);
    return 0;
}

/* --------------------------------------------------------------------- Python API */

static const char *CAPSULE = "smm.int8_mlp.Network";

static void network_free(PyObject *capsule) {
    Network *net = PyCapsule_GetPointer(capsule, CAPSULE);
    if (net == NULL) return;
    for (Py_ssize_t l = 0; l < net->count; ++l) {
        Layer *L = &net->layers[l];
        PyBuffer_Release(&L->weight), free(L->packed), free(L->pairs);
        PyBuffer_Release(&L->column_sum), PyBuffer_Release(&L->weight_scale);
        PyBuffer_Release(&L->bias);
    }
    PyMem_Free(net);
}

/* W (k, n) int8 into AMX's B tiles (k_pad / 64, n_pad / 16, 16, 64): tile row r, byte
 * 4 c + i holds W[64 kb + 4 r + i, 16 nb + c], zero past k and n. */
static void pack(const int8_t *W, Py_ssize_t k, Py_ssize_t n, Py_ssize_t n_pad, int8_t *P) {
    Py_ssize_t n_tiles = n_pad / N_TILE, k_pad = (k + K_BLOCK - 1) / K_BLOCK * K_BLOCK;
    memset(P, 0, (size_t)(k_pad * n_pad));
    for (Py_ssize_t kk = 0; kk < k; ++kk)
        for (Py_ssize_t j = 0; j < n; ++j) {
            Py_ssize_t kb = kk / K_BLOCK, r = kk % K_BLOCK / 4, i = kk % 4;
            Py_ssize_t nb = j / N_TILE, c = j % N_TILE;
            P[(kb * n_tiles + nb) * 1024 + r * 64 + c * 4 + i] = W[kk * n + j];
        }
}

/* network(layers) -> capsule; layers: a tuple of (k, n, silu, weight, column_sum,
 * weight_scale, bias), the buffers checked by int8_mlp.py and held until the capsule goes;
 * the weights packed for AMX here. */
static PyObject *py_network(PyObject *self, PyObject *args) {
    PyObject *layers;
    if (!PyArg_ParseTuple(args, "O!", &PyTuple_Type, &layers)) return NULL;
    Py_ssize_t count = PyTuple_GET_SIZE(layers);
    if (count < 1 || count >= MAX_LAYERS)
        return PyErr_Format(PyExc_ValueError, "a network of %zd layers; 1 to %d taken", count,
                            MAX_LAYERS - 1);
    Network *net = PyMem_Calloc(1, sizeof(Network) + (size_t)count * sizeof(Layer));
    if (net == NULL) return PyErr_NoMemory();
    for (Py_ssize_t l = 0; l < count; ++l) {
        Layer *L = &net->layers[l];
        if (!PyArg_ParseTuple(PyTuple_GET_ITEM(layers, l), "nnpy*y*y*y*", &L->k, &L->n,
                              &L->silu, &L->weight, &L->column_sum, &L->weight_scale,
                              &L->bias)) {
            net->count = l;
            PyObject *partial = PyCapsule_New(net, CAPSULE, network_free);
            Py_XDECREF(partial);
            return NULL;
        }
        L->k_pad = (L->k + K_BLOCK - 1) / K_BLOCK * K_BLOCK;
        L->n_pad = (L->n + N_BLOCK - 1) / N_BLOCK * N_BLOCK;
        net->count = l + 1;
        void *packed = NULL;
        if (posix_memalign(&packed, 64, (size_t)(L->k_pad * L->n_pad)) != 0) {
            PyObject *partial = PyCapsule_New(net, CAPSULE, network_free);
            Py_XDECREF(partial);
            return PyErr_NoMemory();
        }
        L->packed = packed;
        pack(L->weight.buf, L->k, L->n, L->n_pad, L->packed);
#if HAVE_X86_PATHS
        if (avx2_usable()) {
            void *pairs = NULL;
            if (posix_memalign(&pairs, 64, (size_t)(L->k_pad * L->n_pad) * sizeof(int16_t))) {
                PyObject *partial = PyCapsule_New(net, CAPSULE, network_free);
                Py_XDECREF(partial);
                return PyErr_NoMemory();
            }
            L->pairs = pairs;
            pack_pairs(L->weight.buf, L->k, L->n, L->k_pad, L->n_pad, L->pairs);
        }
#endif
        net->widest = L->n > net->widest ? L->n : net->widest;
        net->widest_k = L->k_pad > net->widest_k ? L->k_pad : net->widest_k;
    }
    return PyCapsule_New(net, CAPSULE, network_free);
}

static int kernel_usable(int kernel) {
    return kernel == KERNEL_PLAIN || (kernel == KERNEL_AVX2 && avx2_usable()) ||
           (kernel == KERNEL_VNNI && vnni_usable()) || (kernel == KERNEL_AMX && amx_usable());
}

/* forward(network, x, M, kernel, threads, y): the network on x's M rows into y. */
static PyObject *py_forward(PyObject *self, PyObject *args) {
    PyObject *capsule;
    Py_buffer x, y;
    Py_ssize_t M;
    int kernel, threads;
    if (!PyArg_ParseTuple(args, "Oy*niiw*", &capsule, &x, &M, &kernel, &threads, &y)) return NULL;
    const Network *net = PyCapsule_GetPointer(capsule, CAPSULE);
    int status = 0;
    if (net != NULL && !kernel_usable(kernel)) {
        PyBuffer_Release(&x), PyBuffer_Release(&y);
        return PyErr_Format(PyExc_ValueError, "kernel %d is not usable on this processor", kernel);
    }
    if (net != NULL && M > 0) {
        Py_BEGIN_ALLOW_THREADS
        status = forward(net, x.buf, M, kernel, threads, y.buf);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&x), PyBuffer_Release(&y);
    if (net == NULL) return NULL;
    if (status != 0) return PyErr_NoMemory();
    Py_RETURN_NONE;
}

/* peak_sums() -> PEAK_SUMS: the running sums of avx2_peak. */
static PyObject *py_peak_sums(PyObject *self, PyObject *unused) {
    return PyLong_FromLong(PEAK_SUMS);
}

/* avx2_peak(x, w, rounds) -> the checksum of peak_avx2: x int16 (PEAK_SUMS * 16,), w int16
 * (16,); rounds * 16 * PEAK_SUMS products, the GIL released. */
static PyObject *py_avx2_peak(PyObject *self, PyObject *args) {
    Py_buffer x, w;
    long rounds;
    if (!PyArg_ParseTuple(args, "y*y*l", &x, &w, &rounds)) return NULL;
    PyObject *result = NULL;
    if (!avx2_usable())
        PyErr_SetString(PyExc_ValueError,
                        "avx2_peak needs AVX2 and FMA, which this processor lacks");
    else if (x.len != (Py_ssize_t)(PEAK_SUMS * 16 * sizeof(int16_t)) || w.len != 16 * 2)
        PyErr_Format(PyExc_ValueError,
                     "avx2_peak takes x of %d int16 and w of 16, got %zd and %zd bytes",
                     PEAK_SUMS * 16, x.len, w.len);
    else if (rounds < 0)
        PyErr_Format(PyExc_ValueError, "rounds must be >= 0, got %ld", rounds);
    else {
        int64_t total;
        Py_BEGIN_ALLOW_THREADS
        total = peak_avx2(x.buf, w.buf, rounds);
        Py_END_ALLOW_THREADS
        result = PyLong_FromLongLong(total);
    }
    PyBuffer_Release(&x), PyBuffer_Release(&w);
    return result;
}

/* keep_scratch(bytes) -> the bound it replaces; kept blocks above the new bound are freed. */
static PyObject *py_keep_scratch(PyObject *self, PyObject *args) {
    Py_ssize_t bytes;
    if (!PyArg_ParseTuple(args, "n", &bytes)) return NULL;
    if (bytes < 0) return PyErr_Format(PyExc_ValueError, "bytes must be >= 0, got %zd", bytes);
    void *dropped[SCRATCH_SLOTS] = {NULL};
    PyThread_acquire_lock(scratch_lock, WAIT_LOCK);
    size_t before = scratch_keep_bytes;
    scratch_keep_bytes = (size_t)bytes;
    for (int s = 0; s < SCRATCH_SLOTS; ++s)
        if (scratch_slots[s].block != NULL && scratch_slots[s].bytes > scratch_keep_bytes) {
            dropped[s] = scratch_slots[s].block;
            scratch_slots[s].block = NULL, scratch_slots[s].bytes = 0;
        }
    PyThread_release_lock(scratch_lock);
    for (int s = 0; s < SCRATCH_SLOTS; ++s) free(dropped[s]);
    return PyLong_FromSize_t(before);
}

/* kept_scratch() -> the bytes the kept blocks hold now. */
static PyObject *py_kept_scratch(PyObject *self, PyObject *unused) {
    size_t held = 0;
    PyThread_acquire_lock(scratch_lock, WAIT_LOCK);
    for (int s = 0; s < SCRATCH_SLOTS; ++s) held += scratch_slots[s].bytes;
    PyThread_release_lock(scratch_lock);
    return PyLong_FromSize_t(held);
}

/* kernels() -> the kernels usable here, best first: a tuple of (name, code). */
static PyObject *py_kernels(PyObject *self, PyObject *unused) {
    PyObject *names = PyList_New(0);
    if (names == NULL) return NULL;
    static const struct { const char *name; int code; } all[] = {
        {"amx", KERNEL_AMX}, {"vnni", KERNEL_VNNI}, {"avx2", KERNEL_AVX2},
        {"plain", KERNEL_PLAIN}};
    for (int i = 0; i < (int)(sizeof all / sizeof all[0]); ++i) {
        if (!kernel_usable(all[i].code)) continue;
        PyObject *item = Py_BuildValue("(si)", all[i].name, all[i].code);
        if (item == NULL || PyList_Append(names, item) != 0) {
            Py_XDECREF(item), Py_DECREF(names);
            return NULL;
        }
        Py_DECREF(item);
    }
    PyObject *kernels = PyList_AsTuple(names);
    Py_DECREF(names);
    return kernels;
}

static PyMethodDef methods[] = {
    {"network", py_network, METH_VARARGS,
     "network(layers) -> capsule: the layers (k, n, silu, weight, column_sum, weight_scale, "
     "bias), held for forward, the weights packed for AMX (and widened for AVX2 where it is)."},
    {"forward", py_forward, METH_VARARGS,
     "forward(network, x, M, kernel, threads, y): the network on x's M rows into y on "
     "`kernel` (a code from kernels()); on two threads when threads > 1 and M > 32."},
    {"helper_spin", row_helper_spin, METH_VARARGS,
     "helper_spin(seconds) -> the spin it replaces: how long the row helper waits hot"},
    {"helper_parts", row_helper_parts, METH_NOARGS,
     "helper_parts() -> the second shares the row helper (row_helper.h) has done in this "
     "process"},
    {"keep_scratch", py_keep_scratch, METH_VARARGS,
     "keep_scratch(bytes) -> int: keep scratch blocks of at most `bytes` between calls; "
     "returns the bound it replaces."},
    {"kept_scratch", py_kept_scratch, METH_NOARGS,
     "kept_scratch() -> int: the bytes of the scratch blocks kept now."},
    {"avx2_peak", py_avx2_peak, METH_VARARGS,
     "avx2_peak(x, w, rounds) -> int: `rounds` rounds of PEAK_SUMS vpmaddwd products of x's "
     "int16 vectors (PEAK_SUMS * 16 values) against w's (16), summed: the AVX2 product's "
     "peak, nothing else in the loop; the sum is rounds * the sum of x's vectors' dot "
     "products with w."},
    {"peak_sums", py_peak_sums, METH_NOARGS, "peak_sums() -> int: PEAK_SUMS"},
    {"kernels", py_kernels, METH_NOARGS,
     "kernels() -> ((name, code), ...): the product's kernels usable on this processor, "
     "best first (amx: AMX-INT8 and AVX-512F allowed by the kernel; vnni: AVX-512F, BW "
     "and VNNI; avx2: AVX2 and FMA; plain: any)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_int8_mlp", NULL, -1, methods};

PyMODINIT_FUNC PyInit__int8_mlp(void) {
    scratch_lock = PyThread_allocate_lock();
    if (scratch_lock == NULL) return PyErr_NoMemory();
    return PyModule_Create(&module);
}
