"""This machine's render rates (`studies.estimate.rate`): kept in rates.json with the load they were measured at,
and measured again once the machine is at most half as loaded as then (other work slowed the first measurement)."""
import json

import pytest

import nlosbench as nb
from nlosbench.studies import estimate


@pytest.mark.parametrize("then, now, again", [
    (2.0, 0.1, True),     # measured on a busy machine, now quiet: measured again
    (2.0, 0.6, False),    # still loaded: kept
    (0.3, 0.0, False),    # measured quiet: kept however quiet it is now
    (None, 0.2, True),    # an older entry without its load: measured again on a quiet machine
    (None, 1.5, False),   # ... but not on a busy one
    (2.0, float("nan"), False),  # the system says no load: kept
])
def test_a_rate_measured_under_load_is_measured_again_when_the_machine_is_quieter(tmp_path, monkeypatch, then, now,
                                                                                    again):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    model = nb.scenes.get("blob2d")
    path = estimate.rates_path()
    path.parent.mkdir(parents=True)
    entry = {"seconds_per_sample": 1.0, "seconds_per_render": 1.0, "scene": "blob2d", "when": "2026-01-01"}
    path.write_text(json.dumps({estimate._key(model): {**entry, **({} if then is None else {"load_per_core": then})}}))
    monkeypatch.setattr(estimate, "load_per_core", lambda: now)
    got = estimate.rate(model)
    assert (got.seconds_per_sample != 1.0) == again, got
    kept = json.loads(path.read_text())[estimate._key(model)]
    if again:  # the new measurement keeps its own load
        assert kept["load_per_core"] == pytest.approx(now) and got.source == "measured now"
    else:
        assert kept == {**entry, **({} if then is None else {"load_per_core": then})}
