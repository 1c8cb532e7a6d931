import pytest

from rig import config


def _load(tmp_path, text):
    f = tmp_path / "rig.toml"
    f.write_text(text)
    return config.load(f)


def test_builtin_rig_when_no_file():
    cfg = config.load()
    assert cfg.source == "built-in simulated rig"
    assert list(cfg.arms) == ["PSM1", "PSM2"]
    assert cfg.simulated
    assert cfg.object["arms"] == ["PSM1", "PSM2"] and cfg.object["stiffness"] == 2450.0


def test_rig_toml_in_cwd_is_found(tmp_path):
    (tmp_path / "rig.toml").write_text('[rig]\nseed = 5\n')
    assert config.load().rig["seed"] == 5


@pytest.mark.parametrize("text, message", [
    ('[arms.PSM1]\ndriver = "rosx"\n', "arms.PSM1.driver: must be one of 'sim', 'ros', got 'rosx'"),
    ('[rig]\nrate = -5\n', "rig.rate: must be a rate > 0 Hz"),
    ('[rig]\nseed = "one"\n', "rig.seed: expected an integer"),
    ('[rig]\nsede = 1\n', "rig.sede: unknown key; allowed: seed, rate, pace, gravity"),
    ('[bogus]\n', "bogus: unknown section"),
    ('[arms.PSM1]\nbase_xyz = [1, 2]\n', "arms.PSM1.base_xyz: expected a list of three numbers"),
    ('[loadcell]\ndriver = "serial"\n', "loadcell.port: required"),
    ('[object]\narms = ["PSM1", "PSM7"]\n', "object.arms: 'PSM7' is not an arm"),
    ('[mocap]\nocclusion = 1.5\n', "mocap.occlusion: must be a probability in [0, 1)"),
    ('[effects.PSM1]\nbacklash = [0, 0, -1]\n', "effects.PSM1.backlash: must be plays >= 0"),
    ('[rig\nseed = 1\n', "not valid TOML"),
    ('[loadcell]\ndriver = "serial"\nports = ["/dev/ttyACM0"]\n[arms.PSM1]\n[arms.PSM2]\n[arms.PSM3]\n'
     '[object]\narms = ["PSM1", "PSM2", "PSM3"]\n', "loadcell.ports: the object (PSM1, PSM2, PSM3) has 3 element(s)"),
    ('[loadcell]\ndriver = "can"\nports = ["/dev/ttyACM0"]\n', "loadcell.ports: only with loadcell.driver = 'serial'"),
    ('[ros]\nexecutor = "multi"\n', "ros.executor: must be one of 'events', 'single', got 'multi'"),
])
def test_bad_configuration_is_one_named_line(tmp_path, text, message):
    with pytest.raises(config.ConfigError) as err:
        _load(tmp_path, text)
    line = str(err.value)
    assert "\n" not in line
    assert line.startswith(str(tmp_path / "rig.toml"))
    assert message in line


def test_missing_file_is_named(tmp_path):
    with pytest.raises(config.ConfigError, match="no such configuration file"):
        config.load(tmp_path / "nope.toml")


def test_effects_only_on_simulated_arms(tmp_path):
    with pytest.raises(config.ConfigError, match="only to simulated arms"):
        _load(tmp_path, '[arms.PSM1]\ndriver = "ros"\n[arms.PSM2]\n[effects.PSM1]\nstiction = [0, 0, 1]\n')


def test_real_rig_file_parses(tmp_path):
    cfg = _load(tmp_path, '[arms.PSM1]\ndriver = "ros"\n[arms.PSM2]\ndriver = "ros"\nnamespace = "/dvrk/PSM2"\n'
                          '[loadcell]\ndriver = "serial"\nport = "/dev/ttyACM0"\n[mocap]\ndriver = "ros"\n')
    assert not cfg.simulated
    assert cfg.arms["PSM1"]["namespace"] == "/PSM1" and cfg.arms["PSM2"]["namespace"] == "/dvrk/PSM2"


def test_a_cell_per_element_and_the_rate_of_three_ros_arms(tmp_path):
    arms = "".join(f'[arms.PSM{i}]\ndriver = "ros"\n' for i in (1, 2, 3))
    cfg = _load(tmp_path, arms + '[object]\narms = ["PSM1", "PSM2", "PSM3"]\n[loadcell]\ndriver = "serial"\n'
                                 'ports = ["/dev/ttyACM0", "/dev/ttyACM1", "/dev/ttyACM2"]\nelement = 1\n')
    assert cfg.loadcell["port"] == "/dev/ttyACM1"  # the configured element's, for single-cell commands
    assert cfg.rig["rate"] == config.ROS_DEFAULT_RATE_MANY_ARMS
    two = _load(tmp_path, '[arms.PSM1]\ndriver = "ros"\n[arms.PSM2]\ndriver = "ros"\n')
    assert two.rig["rate"] == config.ROS_DEFAULT_RATE


def test_a_relative_load_cell_port_is_the_configuration_folders(tmp_path, monkeypatch):
    """Two users of one machine each get their own pty link: a relative port lies beside
    the rig.toml, whatever folder the command runs from; an absolute one is kept."""
    lab = tmp_path / "lab"
    lab.mkdir()
    (lab / "rig.toml").write_text('[loadcell]\ndriver = "serial"\nport = "rig-loadcell"\n')
    monkeypatch.chdir(tmp_path)
    assert config.load(lab / "rig.toml").loadcell["port"] == str((lab / "rig-loadcell").resolve())
    (lab / "abs.toml").write_text('[loadcell]\ndriver = "serial"\nport = "/dev/ttyACM0"\n')
    assert config.load(lab / "abs.toml").loadcell["port"] == "/dev/ttyACM0"
