"""The paper's own figures, which the reports and the docs set beside ours: external
numbers from "Approximating High Dimensional Self-Motion Manifolds via Deep Generative
Models", kept in one place. A module with no imports, so the docs' figure blocks read it
without loading torch."""

PAPER_TABLE_2: dict[
    str, dict[str, tuple[float | None, ...]]
] = {  # seed Table 2 (e_p %, e_o %, e %, ms; one target, kept samples, 2000 samples)
    "planar3r-position": {
        "ODE": (2.95e-9, 0.0, 2.95e-9, 166),
        "FM": (0.144, 0.0, 0.144, 125),
        "FM + DLS": (1.56e-14, 0.0, 1.56e-14, 126),
        "Fourier (realtime-smm)": (0.513, 0.0, 0.513, 16.8),
        "Fourier (realtime-smm) + DLS": (5.29e-13, 0.0, 5.29e-13, 29.7),
    },
    "iiwa14-pose": {
        "ODE": (2.57e-10, 2.37e-6, 1.18e-6, 8210),
        "FM": (1.07, 1.70, 1.39, 297),
        "FM + DLS": (2.88e-10, 0.0, 1.44e-10, 375),
        "Fourier (realtime-smm)": (19.9, 47.0, 33.5, 39.9),
        "Fourier (realtime-smm) + DLS": (5.52, 8.46, 6.99, 144),
    },
    # Seed Sec. 5: mean FK error over 1000 targets, before and after correction; no time.
    "iiwa14-position": {
        "FM": (0.0479, None, 0.0479, None),
        "FM + DLS": (0.0013, None, 0.0013, None),
    },
}
