"""The suite's prior cache (``tests/prior_cache.py``) hands out what ``prior_model`` computes:
a fresh copy of the same model per call, one per distinct world and settings, and the copy a
later process reads from the session's folder is the same model."""

from __future__ import annotations

from pathlib import Path

import pytest
from prior_cache import ENV, cached

from rapidds.loop.config import RunConfig
from rapidds.worlds.fetch import FetchWorld


def _real():  # type: ignore[no-untyped-def]
    import rapidds.loop.model as model

    return getattr(model.prior_model, "__wrapped__", model.prior_model)


def test_a_cached_prior_is_a_fresh_fits_copy_per_call(fetch_world: FetchWorld, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ENV, str(tmp_path))
    real = _real()
    cfg = RunConfig().resolved(fetch_world)
    fresh = real(fetch_world, cfg).to_bytes()
    prior = cached(real)
    first, second = prior(fetch_world, cfg), prior(fetch_world, cfg)
    assert first.to_bytes() == second.to_bytes() == fresh
    assert first is not second and first.spatial is not second.spatial  # each run its own
    (stored,) = tmp_path.glob("*.prior")
    assert stored.read_bytes() == fresh
    # another process (a new cache on the same folder) reads it, without fitting
    calls: list[int] = []

    def counted(world, config):  # type: ignore[no-untyped-def]
        calls.append(1)
        return real(world, config)

    assert cached(counted)(fetch_world, cfg).to_bytes() == fresh and calls == []
    other = RunConfig(seed=3).resolved(fetch_world)  # other settings: another prior
    assert cached(counted)(fetch_world, other).to_bytes() == real(fetch_world, other).to_bytes()
    assert calls == [1] and len(list(tmp_path.glob("*.prior"))) == 2
