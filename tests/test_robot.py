"""Loading a robot description: the samples load, bad files are refused naming file and field (exit 2)."""

import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from rxcomm.cli import app
from rxcomm.errors import InputError
from rxcomm.model.robot import load_robot

from .conftest import SAMPLES


def test_rx130l_reference_data(rx130l):
    assert rx130l.n == 6
    np.testing.assert_allclose(np.degrees(rx130l.q_max), [160, 137.5, 150, 270, 120, 270], atol=1e-4)
    np.testing.assert_allclose(np.degrees(rx130l.q_min[4]), -105, atol=1e-4)
    np.testing.assert_allclose(rx130l.tau_max, [692, 574, 242, 58, 29, 29])
    masses = [rx130l.model.inertias[i].mass for i in range(1, 7)]
    np.testing.assert_allclose(masses, [45.4, 38.8, 19.8, 27.6, 0.55, 0.04])
    # Coupled wrist: motor 6 sees axis 5, so the reflected rotor inertia has a J5-J6 term.
    m = rx130l.reflected_rotor_inertia
    assert m[4, 5] == pytest.approx(2.0e-5 * 40**2 * 0.4) and np.allclose(m, m.T)


def test_model_is_immutable(rx130l):
    with pytest.raises(ValueError):
        rx130l.q_max[0] = 0.0
    with pytest.raises(AttributeError):
        rx130l.name = "other"


def _copy(tmp_path, name="rx130l"):
    dst = tmp_path / name
    shutil.copytree(SAMPLES / name, dst)
    return dst


def _edit(path, old, new):
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize(
    ("file", "old", "new", "field"),
    [
        ("drives.yaml", "cycle_s: 0.0004", "cycle_s: 0.0004\nbogus_key: 1", "bogus_key"),
        ("drives.yaml", "gear_ratio: 140,", "gear_ration: 140,", "joints[joint_3]"),
        ("drives.yaml", "peak_torque_nm: 242,", "peak_torque_nm: -242,", "joints[joint_3].peak_torque_nm"),
        ("drives.yaml", "name: joint_6", "name: joint_7", "joints[joint_7].name"),
        ("rx130l.urdf", 'velocity="4.450590"', "", "joint[joint_3].limit.velocity"),
        ("rx130l.urdf", 'ixx="0.42"', 'ixx="-0.42"', "link[link_3].inertial.inertia"),
        ("rx130l.urdf", '<mass value="0.55"/>', '<mass value="-0.55"/>', "link[link_5].inertial.mass"),
        ("drives.yaml", "gear_ratio: 140,", "gear_ratio: -140,", "joints[joint_3].gear_ratio"),
    ],
)
def test_bad_robot_files_exit_2_naming_the_field(tmp_path, file, old, new, field):
    d = _copy(tmp_path)
    _edit(d / file, old, new)
    with pytest.raises(InputError) as e:
        load_robot(d)
    assert e.value.field is not None and e.value.field.startswith(field), e.value
    assert e.value.file.endswith(file)
    result = CliRunner().invoke(app, ["robot-info", "--robot", str(d)])
    assert result.exit_code == 2, result.output
    assert field in result.output and file in result.output


def test_negative_gear_ratio_says_to_use_motor_sign(tmp_path):
    d = _copy(tmp_path)
    _edit(d / "drives.yaml", "gear_ratio: 140,", "gear_ratio: -140,")
    with pytest.raises(InputError) as e:
        load_robot(d)
    assert "motor_sign: -1" in e.value.reason and "140" in e.value.reason


def test_point_mass_and_massless_links_are_legitimate_priors(tmp_path):
    """Positive semi-definite inertias load (a URDF's massless wrist link, a point mass); an
    indefinite one is refused."""
    d = _copy(tmp_path)
    urdf = d / "rx130l.urdf"
    _edit(urdf, '<mass value="0.55"/>', '<mass value="0"/>')
    _edit(
        urdf,
        'ixx="0.00045" ixy="0" ixz="0" iyy="0.00042" iyz="0" izz="0.0003"',
        'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"',
    )
    _edit(
        urdf,
        'ixx="1.2e-05" ixy="0" ixz="0" iyy="1.2e-05" iyz="0" izz="1.8e-05"',
        'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"',
    )
    robot = load_robot(d)
    assert robot.model.inertias[5].mass == 0.0 and robot.model.inertias[6].mass == 0.04
    _edit(
        urdf,
        '<mass value="0.04"/>\n      <inertia ixx="0"',
        '<mass value="0.04"/>\n      <inertia ixx="-1e-6"',
    )
    with pytest.raises(InputError) as e:
        load_robot(d)
    assert e.value.field == "link[link_6].inertial.inertia" and "not physical" in e.value.reason


def test_joint_count_mismatch(tmp_path):
    d = _copy(tmp_path)
    text = (d / "drives.yaml").read_text()
    start = text.index("  - {name: joint_6")
    end = text.index("# Axis-2")
    (d / "drives.yaml").write_text(text[:start] + text[end:].replace("  - [0, 0, 0, 0, 0.4, 1]\n", ""))
    with pytest.raises(InputError) as e:
        load_robot(d)
    assert "motor_coupling" in str(e.value) or "joint" in (e.value.field or "")


def test_missing_robot_dir(tmp_path):
    result = CliRunner().invoke(app, ["robot-info", "--robot", str(tmp_path / "nope")])
    assert result.exit_code == 2
    assert "drives.yaml" in result.output


@pytest.mark.slow
def test_robot_info_shows_why_the_spring_matters():
    result = CliRunner().invoke(app, ["robot-info", "--robot", str(SAMPLES / "rx130l")])
    assert result.exit_code == 0, result.output
    assert "gravity alone needs 527 N·m on joint_2" in result.output
    assert "30 with full-pose measurement, 27 with the position of an off-axis point" in result.output
    # One reach figure: the robot's, which calibrate's unit check also uses.
    assert f"reach                 {load_robot(SAMPLES / 'rx130l').reach_m:.3f} m" in result.output
    assert "1.810 m" in result.output
