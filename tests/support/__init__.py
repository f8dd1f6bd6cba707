"""Helpers shared by the tests: independent kinematics, request bodies, the bad-input catalogue."""
