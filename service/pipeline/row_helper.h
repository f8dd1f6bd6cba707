/* One persistent helper thread that takes the first part of a kernel's rows while the
 * caller does the rest, handed over in C: no GIL, no Python queue, no thread made per call.
 *
 * Why: on a 2-core VM a hand-off through Python (a ThreadPoolExecutor, the GIL) to a thread
 * idle for a millisecond or more takes 100-200 us, against about 11 us when it is hot and
 * under 1 us between two C threads spinning (measured on a 2-core Intel Xeon KVM guest:
 * the idle core's wake-up and the GIL's hand-offs). A request makes several split calls a
 * few milliseconds apart, each waiting for its helper's part. So the helper waits for work
 * by spinning for `row_helper_spin_s` after its last part, yielding the core to any other
 * runnable thread (sched_yield) after the first few microseconds, and only then sleeps on
 * a condition variable. The spin is CPU time spent on a core nothing else wants: worth it
 * after the server has been idle (the cores then start cold), not between requests that
 * come close together (an iiwa14 pose request at N = 500, 20 ms after the last: 17.6-18.3
 * ms with no spin, 14.5-16.4 with 1 ms, 13.1-15.0 with 4 ms, at 21-23, 22-26 and 29-33 ms
 * of CPU; 3 ms after the last, 11.8-12.4 ms either way; through Python's pool 17.8-18.9
 * and 13.0-14.3 ms; ad hoc, in alternating processes).
 *
 * `split_rows(part, context, rows, first)`: part(context, 0, first, 1) on the helper and
 * part(context, first, rows, 0) on the caller, both done when it returns; every row on the
 * caller when the helper is already taken (a concurrent call) or cannot be started. Called
 * without the GIL. Each row's result depends on that row alone in the kernels that use it,
 * so the split never changes a number. A kernel whose two parts meet while they run (the
 * int8 layers) claims the helper first (`row_helper_claim`, then `row_helper_post` and
 * `row_helper_finish`), so that it knows whether it has a second thread before it starts.
 * A file that includes this header gets a helper of its own (static state), started at
 * its first hand-off; a forked child starts its own. */
#ifndef SMM_ROW_HELPER_H
#define SMM_ROW_HELPER_H

#include <pthread.h>
#include <sched.h>
#include <time.h>
#include <unistd.h>

/* Seconds the helper keeps spinning for the next part after finishing one, by default
 * (the service sets it from SMM_ROW_HELPER_SPIN_US; row_helper_spin). */
#define HELPER_SPIN_S 0.001
/* Pause loops before the spinning starts to yield the core (tens of microseconds). */
#define HELPER_HOT_SPINS 2048

/* A kernel's rows [start, stop); `on_helper` 1 on the helper's thread (its own scratch). */
typedef void (*RowPart)(void *context, Py_ssize_t start, Py_ssize_t stop, int on_helper);

typedef struct {
    pthread_mutex_t lock;
    pthread_cond_t wake;
    long posted, finished; /* parts handed over and parts done (atomics) */
    int taken;             /* a caller holds the helper (atomic) */
    int sleeping;          /* the helper waits on `wake` (under `lock`) */
    pid_t owner;           /* the process whose thread it is; 0 before it starts */
    RowPart part;
    void *context;
    Py_ssize_t stop;
} RowHelper;

static RowHelper row_helper = {PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER};
static double row_helper_spin_s = HELPER_SPIN_S; /* read by the helper (atomic) */

/* Python's helper_spin(seconds) -> the spin it replaces: spin this long for the next part
 * (0: sleep at once); ValueError outside 0 to 1 s. Each including extension exposes it. */
static PyObject *row_helper_spin(PyObject *self, PyObject *args) {
    (void)self;
    double seconds, before;
    if (!PyArg_ParseTuple(args, "d", &seconds)) return NULL;
    if (!(seconds >= 0.0 && seconds <= 1.0))
        return PyErr_Format(PyExc_ValueError, "the row helper's spin must be 0 to 1 s, got %R",
                            PyTuple_GET_ITEM(args, 0));
    __atomic_exchange(&row_helper_spin_s, &seconds, &before, __ATOMIC_ACQ_REL);
    return PyFloat_FromDouble(before);
}

/* Python's helper_parts() -> the parts this extension's row helper has done in this
 * process (tests read it to see which calls split). Each including extension exposes it. */
static PyObject *row_helper_parts(PyObject *self, PyObject *args) {
    (void)self;
    (void)args;
    return PyLong_FromLong(__atomic_load_n(&row_helper.finished, __ATOMIC_ACQUIRE));
}

static double row_helper_now_s(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (double)now.tv_sec + 1e-9 * (double)now.tv_nsec;
}

static void row_helper_pause(void) {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#endif
}

static void *row_helper_main(void *unused) {
    (void)unused;
    long seen = 0;
    for (;;) {
        double spin_s;
        __atomic_load(&row_helper_spin_s, &spin_s, __ATOMIC_ACQUIRE);
        double until = row_helper_now_s() + spin_s;
        for (long spins = 0; __atomic_load_n(&row_helper.posted, __ATOMIC_ACQUIRE) == seen;
             ++spins) {
            if (spins < HELPER_HOT_SPINS) {
                row_helper_pause();
                continue;
            }
            sched_yield();
            if (row_helper_now_s() < until) continue;
            pthread_mutex_lock(&row_helper.lock);
            row_helper.sleeping = 1;
            while (__atomic_load_n(&row_helper.posted, __ATOMIC_ACQUIRE) == seen)
                pthread_cond_wait(&row_helper.wake, &row_helper.lock);
            row_helper.sleeping = 0;
            pthread_mutex_unlock(&row_helper.lock);
        }
        seen = __atomic_load_n(&row_helper.posted, __ATOMIC_ACQUIRE);
        row_helper.part(row_helper.context, 0, row_helper.stop, 1);
        __atomic_store_n(&row_helper.finished, seen, __ATOMIC_RELEASE);
    }
    return NULL;
}

/* The helper of this process, started if need be (holding `taken`); 0 when it cannot be. */
static int row_helper_ready(void) {
    pid_t self = getpid();
    if (row_helper.owner == self) return 1;
    /* Not started, or started by the parent of this forked process: a fresh helper. */
    row_helper.posted = row_helper.finished = 0;
    row_helper.sleeping = 0;
    pthread_mutex_init(&row_helper.lock, NULL);
    pthread_cond_init(&row_helper.wake, NULL);
    pthread_attr_t attr;
    pthread_t thread;
    if (pthread_attr_init(&attr) != 0) return 0;
    pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
    int started = pthread_create(&thread, &attr, row_helper_main, NULL) == 0;
    pthread_attr_destroy(&attr);
    if (started) row_helper.owner = self;
    return started;
}

/* Take the helper for one hand-off (starting it if need be): 1, or 0 when another call
 * holds it or it cannot be started (then the caller does every row). */
static int row_helper_claim(void) {
    if (__atomic_exchange_n(&row_helper.taken, 1, __ATOMIC_ACQUIRE)) return 0;
    if (row_helper_ready()) return 1;
    __atomic_store_n(&row_helper.taken, 0, __ATOMIC_RELEASE);
    return 0;
}

/* Hand part(context, 0, stop, 1) to the claimed helper. */
static void row_helper_post(RowPart part, void *context, Py_ssize_t stop) {
    row_helper.part = part;
    row_helper.context = context;
    row_helper.stop = stop;
    __atomic_add_fetch(&row_helper.posted, 1, __ATOMIC_ACQ_REL);
    pthread_mutex_lock(&row_helper.lock);
    if (row_helper.sleeping) pthread_cond_signal(&row_helper.wake);
    pthread_mutex_unlock(&row_helper.lock);
}

/* Wait until the posted part is done, and give the helper back. */
static void row_helper_finish(void) {
    long job = __atomic_load_n(&row_helper.posted, __ATOMIC_ACQUIRE);
    for (long spins = 0; __atomic_load_n(&row_helper.finished, __ATOMIC_ACQUIRE) != job; ++spins)
        if (spins < HELPER_HOT_SPINS)
            row_helper_pause();
        else
            sched_yield();
    __atomic_store_n(&row_helper.taken, 0, __ATOMIC_RELEASE);
}

static void split_rows(RowPart part, void *context, Py_ssize_t rows, Py_ssize_t first) {
    if (first <= 0 || first >= rows || !row_helper_claim()) {
        part(context, 0, rows, 0);
        return;
    }
    row_helper_post(part, context, first);
    part(context, first, rows, 0);
    row_helper_finish();
}

#endif
