"""The deploy folder stays true to the code: every setting is in the environment example."""

from __future__ import annotations

from pathlib import Path

import pytest

from lessmap.settings import LimitSettings, ServiceSettings

ENV_EXAMPLE = Path(__file__).resolve().parents[1] / "deploy" / "lessmap.env.example"


def variables() -> list[str]:
    names = [f"LESSMAP_{n.upper()}" for n in ServiceSettings.model_fields if n != "limits"]
    names += [f"LESSMAP_LIMITS__{n.upper()}" for n in LimitSettings.model_fields]
    return names


@pytest.mark.parametrize("variable", variables())
def test_the_environment_example_lists_every_setting(variable: str) -> None:
    assert f"#{variable}=" in ENV_EXAMPLE.read_text(encoding="utf-8")
