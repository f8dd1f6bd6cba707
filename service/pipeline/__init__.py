"""The request path, one stage per module: target -> sample -> correct -> accept -> connect
-> components.

`run.run()` calls the stages in that order; each stage is a pure function over
numpy arrays and small typed containers (`types.py`).
"""
