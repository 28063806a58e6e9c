"""Every way a hole in a recording can be filled, behind one interface, and the policy that
chooses among them.

fill.py             Fill: the interface (names, fill(positions, observed, fps, skeleton)); candidates
classical.py        Lerp, cubic spline, PCHIP, cubic Hermite, the limb fill (CLASSICAL, Classical)
motion_matching.py  the moments of other takes (or of the take itself) that match a hole's edges
model.py            a model's fill of windows (the model enters as a function)
holes.py            a hole's part and length; holes cut into a take to measure fills on
errors.py           each fill's error on holes cut into takes
policy.py           FillPolicy: fit, choose (part, length -> fill), transform; plain values in checkpoints
jumps.py            which observed tokens a model may replace

Nothing here knows a network, a checkpoint or a file: fix/ and training/ hand in what they have.
"""
