"""The robot's collision model, built at training time from its URDF (and SRDF).

geometry: the URDF's <collision> shapes of every body on the chain or attached to it,
          each in the chain frame it moves with.
spheres:  a conservative sphere cover of each body (every point of it inside a sphere).
pairs:    the body pairs never checked (adjacent, default, always, never; or the SRDF's).
build:    collision.json and the free space the spheres lose, measured with coal.
record:   collision.json written into a model directory, and the manifest's record of it.
command:  `smm-train collision`, the rebuild in an existing model.
The package imports none of its modules: build uses the coal reference
(training.evaluate.references.collision), which uses geometry, so importing either
first must not start the other.
"""
