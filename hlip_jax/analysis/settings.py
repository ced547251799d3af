"""The analysis settings of a sweep (its ``[analysis]`` table), validated once.

Fields, ``name: meaning``:

    splits: the held-out splits coverage.csv reports (:data:`hlip_jax.analysis.splits.SPLITS`);
      a split whose field takes fewer than two values in a group gives that group a note
    methods: the W methods (:data:`hlip_jax.analysis.estimators.METHODS`)
    q: the level of the conformal methods and of the err_q_* quantiles, in (0, 1)
    warmup: errors k < warmup are the start's transient and not counted (e_0 never is;
      :data:`hlip_jax.analysis.masks.WARMUP`) [steps]
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from hlip_jax.analysis import masks, splits

#: the W methods coverage.csv reports by default (``hull`` on request: its 3-D mRPI set takes
#: seconds per group and plane)
DEFAULT_METHODS = ("box", "conformal_step", "conformal_run", "conformal_box")


@dataclass(frozen=True)
class AnalysisConfig:
    """A sweep's analysis settings (module doc)."""
    splits: tuple = ("seed", "path", "speed")
    methods: tuple = DEFAULT_METHODS
    q: float = 0.9
    warmup: int = masks.WARMUP


def _names(value, allowed, where: str) -> tuple:
    if isinstance(value, str) or not isinstance(value, (list, tuple)) or not value:
        raise ValueError(f"{where}: expected a non-empty list of names; allowed: "
                         f"{', '.join(allowed)}")
    for v in value:
        if v not in allowed:
            raise ValueError(f"{where}: {v!r} is not allowed; allowed: {', '.join(allowed)}")
    if len(set(value)) != len(value):
        raise ValueError(f"{where}: a name is listed twice")
    return tuple(value)


def from_dict(raw, where: str = "analysis") -> AnalysisConfig:
    """AnalysisConfig from a TOML table; ValueError with one line naming the field."""
    if raw is None:
        return AnalysisConfig()
    if not isinstance(raw, dict):
        raise ValueError(f"{where}: expected a table")
    known = [f.name for f in dataclasses.fields(AnalysisConfig)]
    for k in raw:
        if k not in known:
            raise ValueError(f"{where}.{k}: unknown field; allowed: {', '.join(known)}")
    cfg = AnalysisConfig()
    if "splits" in raw:
        cfg = dataclasses.replace(cfg, splits=_names(raw["splits"], splits.SPLITS,
                                                     f"{where}.splits"))
    if "methods" in raw:
        from hlip_jax.analysis import estimators    # the registry (imports JAX: only when named)
        cfg = dataclasses.replace(cfg, methods=_names(raw["methods"], estimators.METHODS,
                                                      f"{where}.methods"))
    q = raw.get("q", cfg.q)
    if isinstance(q, bool) or not isinstance(q, (int, float)) or not 0.0 < q < 1.0:
        raise ValueError(f"{where}.q: {q!r} is not allowed; allowed: a number in (0, 1)")
    w = raw.get("warmup", cfg.warmup)
    if isinstance(w, bool) or not isinstance(w, int) or not 0 <= w <= 1000:
        raise ValueError(f"{where}.warmup: {w!r} is not allowed; allowed: an integer in "
                         "[0, 1000]")
    return dataclasses.replace(cfg, q=float(q), warmup=w)


def to_dict(cfg: AnalysisConfig) -> dict:
    """The manifest's record of the settings (lists, so that JSON round-trips them)."""
    return {"splits": list(cfg.splits), "methods": list(cfg.methods), "q": cfg.q,
            "warmup": cfg.warmup}
