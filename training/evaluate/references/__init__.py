"""Exact ground truth, independent of the flow and of the service's kinematics.

planar3r: closed-form FK, Jacobian and SMM of the unit-link planar 3R.
iiwa14:   DH FK and the closed-form S-R-S inverse kinematics of the KUKA iiwa14, the
          exact 1-D pose SMM (8 branches x arm angle) and the 4-D position SMM.
panda:    modified-DH FK of the Franka Panda; the exact 1-D pose SMM (eaik's analytic IK
          with q7 locked, swept over q7 and chained) and the 4-D position SMM.
"""
