"""The evaluation's scene section: random box scenes around the arm, the service's
collision-aware answers in them, checked against coal on the URDF's own geometry
(`smm-train scenes`)."""
