"""Every way a hole in a recording can be filled, and the policy that chooses among them.

classical.py        Lerp, cubic spline, PCHIP, cubic Hermite, the limb fill (CLASSICAL)
motion_matching.py  the moments of other takes (or of the take itself) that match a hole's edges
model.py            a model's fill beside the classical ones (the model enters as a function)
policy.py           FillPolicy: which fill for which hole (part, length), plain values in checkpoints
recording_policy.py the policy measured again on holes cut into the recording being fixed

Nothing here knows a network, a checkpoint or a file: fix/ and training/ hand in what they have.
"""
