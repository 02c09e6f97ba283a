"""Shared fixtures for the identification tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from .signals import paper_record as _paper_record

_CACHE: dict[str, tuple[np.ndarray, np.ndarray]] = {}


@pytest.fixture(scope="session")
def paper_record() -> Callable[[str], tuple[np.ndarray, np.ndarray]]:
    """``name -> (u, y_clean)`` for the paper's four tests, simulated once per session."""

    def get(name: str) -> tuple[np.ndarray, np.ndarray]:
        if name not in _CACHE:
            _CACHE[name] = _paper_record(name)
        return _CACHE[name]

    return get
