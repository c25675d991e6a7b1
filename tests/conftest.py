"""Shared factories: tiny recipes and models, built once per session where costly."""

import os

import pytest

os.environ.setdefault("MUJOCO_GL", "disable")


@pytest.fixture(scope="session")
def nominal_model():
    from robomorph.sim import panda

    return panda.build_model()
