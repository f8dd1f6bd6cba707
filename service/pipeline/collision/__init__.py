"""Collision checks on the robot's own bodies and the request's obstacles (spheres fitted to
the URDF's collision geometry at training time, obstacles as primitives), pure numpy."""
