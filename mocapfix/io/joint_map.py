"""A --joint-map file: YAML, `input name: model name` per line (rig/mapping.py uses the map)."""

from __future__ import annotations

from mocapfix.core.skeleton import Skeleton

JOINT_MAP_BYTES = 4 << 20  # a line per joint: 4 MiB is tens of thousands of joints


def read_joint_map(path) -> dict[str, str]:
    """A --joint-map file: YAML, `input name: model name` per line -> dict. Anything else is a
    MotionFileError naming the file."""
    from pathlib import Path

    import yaml

    from mocapfix.core.clip import MotionFileError
    from mocapfix.io.untrusted import printable, read_bytes

    path = Path(path)
    try:  # a regular file only (a FIFO would wait forever), and no larger than a map of 10,000s of joints
        data = yaml.safe_load(read_bytes(path, "joint map", limit=JOINT_MAP_BYTES).decode("utf-8"))
    except OSError as e:
        raise MotionFileError(path, f"cannot read the joint map ({e.strerror or e})") from None
    except UnicodeDecodeError as e:
        raise MotionFileError(path, f"the joint map is not UTF-8 text (byte {e.start})") from None
    except yaml.YAMLError as e:  # its str() quotes the offending line: say where instead
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = printable(getattr(e, "problem", None) or type(e).__name__, 80)
        raise MotionFileError(path, f"not a YAML joint map ({where}{problem})") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise MotionFileError(path, "a joint map is `input name: model name` per line")
    return dict(data)


def check_joint_map(joint_map: dict[str, str], model: Skeleton, path) -> None:
    """A --joint-map names model joints on its right-hand side: one the model does not have is a
    typo that would otherwise be ignored, so it is a MotionFileError naming the map file."""
    from mocapfix.core.clip import MotionFileError
    from mocapfix.io.untrusted import quoted

    unknown = [v for v in joint_map.values() if v not in model.joint_names]
    if unknown:
        more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
        raise MotionFileError(
            path,
            f"maps onto {', '.join(quoted(v) for v in unknown[:5])}{more}, not joints of the model "
            f"({model.name}: {', '.join(model.joint_names)})",
        )
