"""A fit's hyperparameters beside its best validation results, for TensorBoard's HPARAMS tab
(training/tracking.py): read back from the event files as TensorBoard reads them."""

from __future__ import annotations

import math

from cli_utils import CONFIGS, QUIET, SMALL_DATA, TINY, run_cli

from mocapfix.training.tracking import METRICS


def read_run(run_dir):
    """-> (scalars: tag -> values, hparams: name -> value, end status)"""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.hparams import api_pb2, metadata

    ea = EventAccumulator(str(run_dir), size_guidance={"scalars": 0})
    ea.Reload()
    scalars = {tag: [e.value for e in ea.Scalars(tag)] for tag in ea.Tags()["scalars"]}

    def content(tag):
        return ea.SummaryMetadata(tag).plugin_data.content

    start = metadata.parse_session_start_info_plugin_data(content(metadata.SESSION_START_INFO_TAG))
    hparams = {k: getattr(v, v.WhichOneof("kind")) for k, v in start.hparams.items()}
    # no experiment record: TensorBoard builds it from the runs, the settings that differ first
    assert metadata.EXPERIMENT_TAG not in ea.summary_metadata
    end = metadata.parse_session_end_info_plugin_data(content(metadata.SESSION_END_INFO_TAG))
    return scalars, hparams, api_pb2.Status.Name(end.status)


def test_fit_logs_its_hyperparameters_beside_its_best_validation(tmp_path):
    args = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *TINY,
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "hp",
        "--trainer.max_steps",
        "4",
        "--trainer.val_check_interval",
        "2",
        "--model.init_args.mask_ratio",
        "0.8",
        "--model.init_args.calibration_windows",
        "0",
    ]
    assert run_cli(args, tmp_path) == 0
    scalars, hparams, status = read_run(tmp_path / "logs" / "hp" / "version_0")

    # the main settings, flat, named as on the command line; the network's sizes as resolved
    expected = {
        "model": "XMAEModule",
        "model.preset": "paper",
        "model.enc_dim": 32,
        "model.mask_ratio": 0.8,
        "model.displace_ratio": 0.05,
        "model.lr": 3e-4,
        "model.betas": "0.9, 0.999",
        "data.source": "synthetic",
        "data.window_s": 1.0,
        "data.batch_size": 4,
        "trainer.max_steps": 4,
        "seed": 0,
    }
    for name, value in expected.items():
        assert hparams.get(name) == value, f"{name}: {hparams.get(name)!r} (hparams: {sorted(hparams)})"
    assert not any("skeleton" in k or k.startswith("model._") for k in hparams)
    assert "data.num_workers" not in hparams and "data.cache_dir" not in hparams
    assert set(METRICS) <= set(scalars) and status == "STATUS_SUCCESS"

    # the metrics are measurements: the best of two validations, and XMAE over the cubic spline
    assert "hp_metric" not in scalars, "Lightning's placeholder hp_metric card"
    assert "epoch" not in scalars, "steps count here; the epoch card was the first a user met"
    best = scalars["hparams/best_val_mpjpe_mm"]
    assert len(scalars["val/mpjpe_mm"]) == 2 and len(best) == 2
    assert all(math.isfinite(v) and v > 0 for v in best)
    assert best[-1] == min(scalars["val/mpjpe_mm"])
    assert scalars["hparams/best_val_loss"][-1] == min(scalars["val/loss"])
    ratio = scalars["hparams/val_vs_spline"][-1]
    which = scalars["val/mpjpe_mm"].index(best[-1])
    assert math.isclose(ratio, scalars["val/gap_vs_spline"][which], rel_tol=1e-6) and ratio > 0
    xmae, spline = scalars["val/gap0.5s_mpjpe_mm/xmae"][which], scalars["val/gap0.5s_mpjpe_mm/spline"][which]
    assert math.isclose(ratio, xmae / spline, rel_tol=1e-4)


def test_the_end_statuses_written_are_tensorboards():
    # a status TensorBoard lacks (STATUS_ABORTED) once turned a SIGTERM stop into an error
    from mocapfix.training.tracking import hparams_summaries

    for status in ("STATUS_SUCCESS", "STATUS_FAILURE"):
        (summary,) = hparams_summaries({}, status)
        assert summary.value[0].tag.endswith("session_end_info")
