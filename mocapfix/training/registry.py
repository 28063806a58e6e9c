"""The LightningModules mocapfix trains, by model kind (the kinds of models/build.py): the only
classes a checkpoint may name. A checkpoint's hyperparameters carry the class that wrote it as a
string (`_class_path`), and LightningCLI would import whatever module that string names: the
class is looked up here instead, so a checkpoint handed over by someone else runs no code."""

from __future__ import annotations

# kind -> the module's import path, as configs/model/*.yaml name it and as LightningCLI saves it
MODULES: dict[str, str] = {
    "xmae": "mocapfix.training.xmae_module.XMAEModule",
    "motion-dvae-prior": "mocapfix.training.dvae_module.MotionDVAEModule",
    "motion-dvae": "mocapfix.training.denoise_module.DVAEDenoiseModule",
    "jitter": "mocapfix.training.jitter_module.JitterModule",
    "correction": "mocapfix.training.correction_module.CorrectionModule",
}


def is_mocapfix_module(class_path) -> bool:
    """Whether a class path (a checkpoint's string) is one of mocapfix's training modules: an exact
    match, never an import."""
    return isinstance(class_path, str) and class_path in MODULES.values()


def allowed() -> str:
    """The class paths a checkpoint may name, for an error line."""
    return ", ".join(MODULES.values())


def checked_hyperparameters(path, hparams) -> dict:
    """A checkpoint's hyper_parameters -> the model settings LightningCLI parses over the config:
    {"class_path": one of MODULES, "dict_kwargs": settings}, or the settings alone when the
    checkpoint names no class (the config's class then). ValueError naming the file when they
    name any other class, anywhere: jsonargparse imports the module of every class_path it meets."""
    if hparams is None:
        return {}
    if not isinstance(hparams, dict):
        raise ValueError(f"{path}: not a mocapfix checkpoint (its hyper_parameters are not a table of settings)")
    # Lightning's own instantiator entry; LightningCLI drops it too
    settings = {k: v for k, v in hparams.items() if k not in ("_instantiator", "_class_path")}
    class_path = hparams.get("_class_path")
    if (class_path is not None and not is_mocapfix_module(class_path)) or _names_a_class(settings):
        raise ValueError(
            f"{path}: the checkpoint names a model class that is not one of mocapfix's (mocapfix's: {allowed()})"
        )
    return settings if class_path is None else {"class_path": class_path, "dict_kwargs": settings}


def _names_a_class(value) -> bool:
    """Whether a class_path key (jsonargparse's: import this) sits anywhere in nested settings."""
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            if "class_path" in item:
                return True
            stack.extend(item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend(item)
    return False
