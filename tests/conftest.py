"""Shared fixtures. Mitsuba scenes load once per test session (scene loads are the slow part)."""
import numpy as np
import pytest

import nlosbench as nb


@pytest.fixture(scope="session")
def cornell():
    """The real 32×32 Mitsuba `cornell_ball` scene (llvm_ad_rgb on CPU)."""
    return nb.scenes.get("cornell_ball")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
