"""The digital twin: scenarios, motion, traffic, the RF world and the captures it writes.

The world model sits below ``sources/``: the ``virtual:`` source and the capture
writers read it, and it imports nothing above the DF stage. Everything it makes
(radiotap pcaps, board streams, observations) goes through the real pipeline.
"""
