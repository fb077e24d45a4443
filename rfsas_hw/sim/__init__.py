"""The digital twin: scenarios, the RF world, captures, scan plans and the braking case.

Everything here feeds the real pipeline (captures, board streams, the
``virtual:`` source); nothing bypasses DF, hashing, the link or the backend.
"""
