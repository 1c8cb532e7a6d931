"""A mistyped rig.toml key or table says what was meant, in its one line (issue 36, point 9)."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from rig import config
from rig.cli import main


@pytest.mark.parametrize("text, hint", [
    ('[rig]\nsede = 1\n', "rig.sede: unknown key; allowed: seed, rate, pace, gravity; did you mean rig.seed?"),
    ('[arms.PSM1]\nnamesapce = "/PSM1"\n', "; did you mean arms.PSM1.namespace?"),
    ('[loadcell]\nbaud = 250000\n', "; did you mean loadcell.baudrate?"),
    ('[loadcel]\ndriver = "sim"\n', "loadcel: unknown section; allowed: rig, arms, loadcell, mocap, object, effects, "
                                    "ros, operator; did you mean loadcell?"),
    ('[rig]\nport = "/dev/ttyACM0"\n', "; port is a key of [loadcell]: did you mean loadcell.port?"),
    ('[arms.PSM1]\nrate = 500.0\n', "; rate is a key of [rig], [loadcell], [mocap]"),
    ('[effects.psm1]\nstiction = [0.0, 0.0, 1.0]\n', "effects.psm1: not an arm; arms: PSM1, PSM2; did you mean "
                                                     "effects.PSM1?"),
])
def test_a_typo_says_did_you_mean(tmp_path, text, hint):
    path = tmp_path / "rig.toml"
    path.write_text(text)
    with pytest.raises(config.ConfigError) as err:
        config.load(path)
    assert hint in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_no_guess_for_a_key_like_no_other(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text("[rig]\nzzzz = 1\n")
    with pytest.raises(config.ConfigError) as err:
        config.load(path)
    assert str(err.value).endswith("rig.zzzz: unknown key; allowed: seed, rate, pace, gravity")


def test_the_command_line_shows_it_in_one_line(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "rig.toml").write_text("[rig]\nsede = 1\n")
    res = CliRunner().invoke(main, ["loadcell-calibrate", "--seconds", "0.2"])
    assert res.exit_code != 0 and "Traceback" not in res.output
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].endswith("did you mean rig.seed?"), lines
