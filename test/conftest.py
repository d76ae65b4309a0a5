"""Suite-wide fixtures: every test starts from the same random state, so a failure reproduces."""
from __future__ import annotations

import random

import numpy as np
import pytest
import torch
from browser import chromium  # noqa: F401  (the headless-browser fixture, test/browser.py)

# the longest test files start first (test/suite_order.py); simulated flights and runs shared by the
# files (test/flights.py)
pytest_plugins = ['suite_order', 'flights']


@pytest.fixture(autouse=True)
def _seed_global_rngs():
    """Seed torch, numpy's legacy global RNG and `random` before each test (tests that need
    their own streams make explicit generators; this only removes hidden nondeterminism)."""
    torch.manual_seed(0)
    np.random.seed(0)
    random.seed(0)
    yield
