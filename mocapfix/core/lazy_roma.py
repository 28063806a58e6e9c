"""roma (rotations, reference.md), imported on its first use rather than at every start:
importing roma imports torch._dynamo, over a second of CPU, and `fix` on position files never
turns a rotation. `from mocapfix.core import lazy_roma as roma`; then `roma.rotvec_to_rotmat(...)`
as with roma itself (a module __getattr__, PEP 562)."""


def __getattr__(name: str):
    import roma

    return getattr(roma, name)
