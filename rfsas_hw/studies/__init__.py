"""End-to-end runs over the twin: the bundled demo and the braking-delay study.

These sit above ``backend/``: they drive the sensor pipeline, the link and the
backend on what the twin produces, and never shortcut any of them.
"""
