"""One error hierarchy: everything c3swarm raises on purpose is a SwarmError."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.config import ConfigError, resolve
from swarm.errors import DecodeError, InputError, SwarmError
from swarm.model import QuadState
from swarm.net.access import SecretsError, password
from swarm.net.messages import decode
from swarm.safety.filter import FilterConfig


def test_each_error_is_a_swarm_error_and_its_builtin() -> None:
    for cls, builtin in (
        (InputError, ValueError),
        (ConfigError, ValueError),
        (DecodeError, ValueError),
        (SecretsError, RuntimeError),
    ):
        assert issubclass(cls, SwarmError) and issubclass(cls, builtin)


def test_the_raised_errors_are_caught_by_the_base(tmp_path) -> None:
    with pytest.raises(SwarmError, match="rho"):
        FilterConfig(rho=2.0)
    with pytest.raises(SwarmError, match="duration_s"):
        resolve({"version": 1, "name": "x", "duration_s": -1, "agents": []}, "x.yaml")
    with pytest.raises(SwarmError):
        decode(b"\x00garbage", "run")
    with pytest.raises(SwarmError):
        password(tmp_path, "nobody")
    with pytest.raises(SwarmError, match="x_w"):
        QuadState.hover([np.nan, 0.0, 1.0]).validated()


def test_the_filter_setting_has_the_configs_name() -> None:
    from swarm.config import FilterSettings
    from swarm.model import CommandLevel
    from swarm.safety.barriers import BarrierKind

    cfg = FilterSettings(kind="hocbf").filter_config(CommandLevel.ATTITUDE)
    assert cfg.kind is BarrierKind.HOCBF and not hasattr(cfg, "barrier")
