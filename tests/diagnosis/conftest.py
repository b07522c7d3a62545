"""Fixtures shared by the diagnosis tests. The suite imports test modules in importlib mode,
so the factories of real diagnosis objects (``factories.py`` beside this file) reach the
tests as fixtures."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.verdict.types import Judgement, Verdict


def _load_factories() -> ModuleType:
    name = "realitygap_tests_diagnosis_factories"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            name, Path(__file__).with_name("factories.py")
        )
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # dataclasses look their module up by name
        spec.loader.exec_module(module)
    return sys.modules[name]


factories = _load_factories()


@pytest.fixture
def model_fit() -> Callable[..., ModelFit]:
    """Build a :class:`ModelFit` (``effects``, ``z_heldout``, ``values``, …; keywords)."""
    return factories.model_fit


@pytest.fixture
def make_prepared() -> Callable[..., Any]:
    """Build a :class:`PreparedLog` of ``n`` windows without a gap (``name``, ``split``, ``n``)."""
    return factories.prepared_log


@pytest.fixture
def toy_problem() -> Callable[..., Problem]:
    """Build a :class:`Problem` on the toy robot of planted residuals (keywords)."""
    return factories.toy_problem


@pytest.fixture
def make_judgement() -> Callable[..., Judgement]:
    """Build a :class:`Judgement` on a model and a nominal residual (keywords)."""
    return factories.judgement


@pytest.fixture
def make_verdict() -> Callable[..., Verdict]:
    """Build a :class:`Verdict` (keywords)."""
    return factories.verdict


@pytest.fixture
def toy_schema() -> Callable[..., object]:
    """Build a schema of real feature groups for :func:`toy_problem`."""
    return factories.toy_schema
