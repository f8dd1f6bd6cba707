"""What a user would run instead of the flow, measured beside it on the same targets.

ode.py:         the paper's ODE baseline: trace the 1-D null space of the Jacobian
                (Cash-Karp RK5) from one configuration on the fibre.
restart_dls.py: random-restart damped least squares (pytorch-kinematics PseudoInverseIK).
fourier.py:     the paper's Fourier baseline (Clark and Xie): realtime-smm's per-cluster
                Fourier-series regressors, planar 3R only (installed apart: --no-deps).
"""
