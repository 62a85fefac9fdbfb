"""Checks of a saved :class:`~edge_monitor.stats.sequential_detector.SequentialDetector` state: a state
file is untrusted input, so every learned part is checked against what a detector with its config could
have saved; anything else raises ``ValueError`` (the joint then relearns, with a warning)."""

from __future__ import annotations

import math
from typing import Any

from edge_monitor.stats.calibration import MAX_ARL0, MIN_ARL0
from edge_monitor.stats.normalising_transform import YeoJohnson


def saved_target(saved: Any) -> float:
    """A saved ARL0 target [cycles], checked like the config's."""
    if isinstance(saved, bool) or not isinstance(saved, (int, float)) or not MIN_ARL0 <= saved <= MAX_ARL0:
        raise ValueError(f"saved detector state: ARL0 target {saved!r} outside {MIN_ARL0:g} … {MAX_ARL0:g} cycles")
    return float(saved)


def saved_transform(saved: Any, det: Any) -> YeoJohnson | None:
    """A saved transform, checked: only a monitoring steady detector with the transform on has one, of its
    dimension, with λ = 1 on the axes it does not select."""
    if saved is None:
        return None
    transform = YeoJohnson.from_state(saved)          # TransformError is a ValueError: a damaged state
    selected = det.config.transform_axes or (True,) * det.dim
    fits = (det.config.steady_transform != "none" and transform.dim == det.dim == len(selected)
            and all(on or lam == 1.0 for on, lam in zip(selected, transform.lambdas)))
    if det.stage != "steady" or det.glr is None or not fits:
        raise ValueError("saved detector state: a transform that no detector could have learned")
    return transform


def saved_steady_values(saved: Any, det: Any) -> list[list[float]] | None:
    """A saved steady collection, checked: only a monitoring warm-up detector collects, fewer than
    ``steady_nominal`` values of ``dim`` finite numbers each; anything else is a damaged state."""
    if saved is None:
        return None
    values = [list(map(float, v)) for v in saved]
    ok = (det.stage == "warm-up" and det.glr is not None and len(values) < det.config.steady_nominal
          and all(len(v) == det.dim and all(map(math.isfinite, v)) for v in values))
    if not ok:
        raise ValueError("saved detector state: steady values that no detector could have collected")
    return values


def recalibrated(job: Any, calibration: dict[str, Any]) -> bool:
    """Whether a restored calibration ``job`` was calibrated elsewhere than ``calibration`` (the
    :class:`~edge_monitor.stats.calibration.CalibrationJob` fields its config gives now): the settings changed
    since, and the saved nominal's threshold is re-derived rather than the nominal relearned."""
    return any(getattr(job, k) != v for k, v in calibration.items())
