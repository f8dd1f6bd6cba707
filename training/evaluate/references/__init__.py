"""Exact ground truth, independent of the flow and of the service's kinematics: the one
home of the reference kinematics, which the evaluation, the tests and
tools/container_test all import (each table and closed form is written here once).

planar3r:   closed-form FK, Jacobian and SMM of the unit-link planar 3R.
iiwa14:     the DH table, DH FK and the closed-form S-R-S inverse kinematics of the KUKA
            iiwa14, the exact 1-D pose SMM (8 branches x arm angle) and the 4-D position SMM.
panda:      modified-DH FK of the Franka Panda; the exact 1-D pose SMM (eaik's analytic IK
            with q7 locked, swept over q7 and chained) and the 4-D position SMM.
urdf_chain: a float64 FK and Jacobian of any URDF chain (xml.etree, Rodrigues): what the
            tests check the DH tables against, and the container test the Panda with.
rotations:  the angle between two rotations, and the rotation about an axis.
collision:  coal on a URDF's own collision geometry placed by the chain frames: self and
            obstacle distances and collisions, what the sphere model is checked against.
"""
