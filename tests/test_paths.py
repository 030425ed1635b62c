"""Cartesian paths (arc length, derivatives, blends, orientation), the path file, ISO 9283 geometry,
and IK along a path (continuity, accuracy, named failures)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from pydantic import ValidationError

from rxcomm.errors import InfeasibleError, InputError
from rxcomm.io.yaml_io import load_yaml
from rxcomm.planning.iso9283 import Iso9283Cube, _cube_geometry, iso9283_paths
from rxcomm.planning.path_ik import solve_path_ik
from rxcomm.planning.paths import BlendCurve, build_path
from rxcomm.schemas.path import PathSpec

SAMPLES = Path(__file__).resolve().parent.parent / "samples"


def spec(geometry: dict, **kw) -> PathSpec:
    data = {"kind": "rxcomm/Path", "schema_version": 1, "name": "t", "geometry": geometry}
    data["orientation"] = kw.pop("orientation", {"rpy_deg": [180, 45, 180]})
    return PathSpec.model_validate(data | kw)


def fd_check(curve, s: np.ndarray, h: float = 1e-6) -> tuple[float, float]:
    """Largest |p' − FD(p)| and |p'' − FD(p')| at s."""
    d1 = (curve.eval(s + h) - curve.eval(s - h)) / (2 * h)
    d2 = (curve.eval(s + h, 1) - curve.eval(s - h, 1)) / (2 * h)
    return float(np.abs(d1 - curve.eval(s, 1)).max()), float(np.abs(d2 - curve.eval(s, 2)).max())


# --- geometry ---------------------------------------------------------------------------------------


def test_line_is_unit_speed_and_straight():
    p = build_path(spec({"type": "line", "start_m": [1, 0, 0], "end_m": [1, 0.3, 0.4]}))
    assert p.length_m == pytest.approx(0.5)
    s = np.linspace(0, 0.5, 11)
    np.testing.assert_allclose(p.position(s)[-1], [1, 0.3, 0.4], atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(p.position(s, 1), axis=1), 1.0, atol=1e-15)
    assert np.abs(p.position(s, 2)).max() == 0.0


def test_circle_through_three_points():
    pts = [[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [-1.0, 0.0, 0.5]]
    arc = build_path(spec({"type": "circle", "points_m": pts}))
    assert arc.length_m == pytest.approx(np.pi)  # half circle of radius 1, through (0, 1)
    np.testing.assert_allclose(arc.position([np.pi / 2])[0], pts[1], atol=1e-12)
    np.testing.assert_allclose(arc.position([np.pi])[0], pts[2], atol=1e-12)
    s = np.linspace(0.1, 3.0, 7)
    np.testing.assert_allclose(np.linalg.norm(arc.position(s, 2), axis=1), 1.0, atol=1e-12)  # κ = 1/r
    e1, e2 = fd_check(arc.curve, s)
    assert e1 < 1e-8 and e2 < 1e-6
    full = build_path(spec({"type": "circle", "points_m": pts, "full": True}))
    assert full.length_m == pytest.approx(2 * np.pi)
    np.testing.assert_allclose(full.position([full.length_m])[0], pts[0], atol=1e-12)


def test_circle_from_centre_normal_radius_and_direction_of_turn():
    geo = {
        "type": "circle",
        "centre_m": [0, 0, 1],
        "normal": [0, 0, 1],
        "radius_m": 0.2,
        "start_direction": [1, 0, 0],
    }
    ccw = build_path(spec(geo | {"sweep_rad": np.pi / 2}))
    cw = build_path(spec(geo | {"sweep_rad": -np.pi / 2}))
    np.testing.assert_allclose(ccw.position([0.0])[0], [0.2, 0, 1], atol=1e-15)
    np.testing.assert_allclose(ccw.position([ccw.length_m])[0], [0, 0.2, 1], atol=1e-12)
    np.testing.assert_allclose(cw.position([cw.length_m])[0], [0, -0.2, 1], atol=1e-12)


def test_blended_polyline_has_continuous_tangent_and_curvature():
    pts = [[0.8, -0.3, 0.5], [0.8, 0.3, 0.5], [1.1, 0.3, 0.8]]
    p = build_path(spec({"type": "polyline", "points_m": pts, "blend_radius_m": 0.05}))
    sharp = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
    assert p.length_m < sharp
    b = p.curve.breaks  # junctions line | blend | line
    for s in b[1:-1]:
        np.testing.assert_allclose(p.position([s - 1e-9], 1), p.position([s + 1e-9], 1), atol=1e-7)
        assert np.linalg.norm(p.position([s - 1e-9], 2)) < 1e-4  # zero curvature on both sides
        assert np.linalg.norm(p.position([s + 1e-9], 2)) < 1e-4
    s = np.linspace(b[1] + 1e-4, b[2] - 1e-4, 9)
    e1, e2 = fd_check(p.curve, s)
    assert e1 < 1e-7 and e2 < 1e-4
    np.testing.assert_allclose(np.linalg.norm(p.position(s, 1), axis=1), 1.0, atol=1e-9)


def test_blend_curvature_peaks_inside_the_zone():
    c = BlendCurve(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 0.01)
    kappa = np.linalg.norm(c.eval(np.linspace(0, c.length_m, 41), 2), axis=1)
    assert kappa[0] < 1e-9 and kappa[-1] < 1e-9
    assert 100 < kappa.max() < 200  # a 90° turn within ±1 cm of the corner


def test_spline_through_waypoints_is_unit_speed():
    pts = [[0.8, -0.3, 0.5], [0.9, 0.0, 0.6], [0.85, 0.2, 0.55], [1.0, 0.35, 0.5]]
    p = build_path(spec({"type": "spline", "points_m": pts}))
    s = np.linspace(0, p.length_m, 201)
    np.testing.assert_allclose(np.linalg.norm(p.position(s, 1), axis=1), 1.0, atol=1e-8)
    d = np.linalg.norm(p.position(s)[:, None, :] - np.array(pts)[None], axis=2).min(axis=0)
    assert d.max() < 2e-3  # passes through every waypoint (to the sampling)
    e1, e2 = fd_check(p.curve, s[1:-1])
    assert e1 < 1e-7 and e2 < 1e-4


def test_slerp_orientation_and_its_rate():
    o = {"mode": "slerp", "rpy_deg": [180, 0, 0], "end_rpy_deg": [180, 30, 90]}
    p = build_path(spec({"type": "line", "start_m": [1, 0, 0.5], "end_m": [1, 0.4, 0.5]}, orientation=o))
    r0, r1 = p.rotation([0.0, p.length_m])
    np.testing.assert_allclose(r0, pin.rpy.rpyToMatrix(np.radians([180, 0, 0])), atol=1e-12)
    np.testing.assert_allclose(r1, pin.rpy.rpyToMatrix(np.radians([180, 30, 90])), atol=1e-12)
    s, h = 0.17, 1e-6
    ra, rb = p.rotation([s - h, s + h])
    w_fd = pin.log3(rb @ ra.T) / (2 * h)  # base-frame angular rate per metre
    np.testing.assert_allclose(p.twist_rate([s])[0, 3:], w_fd, atol=1e-6)


@pytest.mark.parametrize(
    ("geometry", "field"),
    [
        ({"type": "line", "start_m": [1, 0, 0], "end_m": [1, 0, 0]}, "geometry.end_m"),
        ({"type": "polyline", "points_m": [[1, 0, 0], [1, 0, 0], [1, 1, 0]]}, "geometry.points_m[1]"),
        ({"type": "spline", "points_m": [[1, 0, 0], [1, 0.5, 0], [1, 0.5, 0]]}, "geometry.points_m[2]"),
        ({"type": "circle", "points_m": [[0, 0, 0], [1, 1, 1], [2, 2, 2]]}, "geometry.points_m"),
        (
            {
                "type": "polyline",
                "points_m": [[1, 0, 0], [1, 0.1, 0], [1.1, 0.1, 0], [1.1, 0.3, 0]],
                "blend_radius_m": 0.06,
            },
            "geometry.blend_radius_m",
        ),
        ({"type": "polyline", "points_m": [[1, 0, 0], [1, 0.5, 0], [1, 0.2, 0]]}, "geometry.points_m[1]"),
    ],
)
def test_degenerate_geometry_is_refused_by_field(geometry, field):
    with pytest.raises(InputError) as e:
        build_path(spec(geometry))
    assert e.value.field == field


def test_path_spec_is_strict():
    good = {
        "kind": "rxcomm/Path",
        "schema_version": 1,
        "geometry": {"type": "line", "start_m": [1, 0, 0], "end_m": [1, 1, 0]},
    }
    PathSpec.model_validate(good | {"orientation": {"rpy_rad": [3.14, 0, 0]}})
    for bad in (
        good | {"orientation": {"rpy_rad": [3.14, 0, 0]}, "speed": 1},  # unknown key
        good | {"orientation": {"rpy_rad": [3.14, 0, 0], "rpy_deg": [180, 0, 0]}},  # both units
        good | {"orientation": {"mode": "slerp", "rpy_deg": [180, 0, 0]}},  # slerp without an end
        good
        | {
            "orientation": {"rpy_deg": [180, 0, 0]},
            "geometry": {"type": "circle", "points_m": [[0, 0, 0]] * 3, "radius_m": 0.1},
        },
    ):
        with pytest.raises(ValidationError):
            PathSpec.model_validate(bad)


@pytest.mark.parametrize("robot_name", ["rx130l", "m900"])
def test_sample_paths_load_and_build(robot_name):
    files = sorted((SAMPLES / robot_name / "paths").glob("*.yaml"))
    assert {f.stem for f in files} >= {"iso9283-line", "iso9283-circle-large"}
    for f in files:
        p = build_path(PathSpec.model_validate(load_yaml(f)))
        assert p.length_m > 0.05


# --- ISO 9283 ---------------------------------------------------------------------------------------


def test_iso9283_plane_points_and_paths():
    centre, side = np.array([0.9, 0.0, 0.6]), 0.8
    corners, pts = _cube_geometry(centre, side)
    # The plane runs through the near bottom edge and the far top edge (x away from the robot).
    assert np.allclose(corners[:2, [0, 2]], [[0.5, 0.2], [0.5, 0.2]])
    assert np.allclose(corners[2:, [0, 2]], [[1.3, 1.0], [1.3, 1.0]])
    diag = np.linalg.norm(corners[2] - corners[0])
    assert diag == pytest.approx(np.sqrt(3) * side)  # the plane's diagonal is the cube's
    for k, c in zip(("P2", "P3", "P4", "P5"), corners, strict=True):
        assert np.linalg.norm(pts[k] - c) == pytest.approx(0.1 * diag)
        assert np.linalg.norm(pts[k] - centre) == pytest.approx(0.4 * diag)
    cube = Iso9283Cube(centre, side, (np.pi, 0.0, 0.0), corners, pts)
    specs = iso9283_paths(cube)
    line = build_path(specs["iso9283-line"])
    assert line.length_m == pytest.approx(0.8 * diag, rel=1e-6)
    circle = build_path(specs["iso9283-circle-large"])
    assert circle.length_m == pytest.approx(np.pi * 0.8 * side, rel=1e-6)
    normal = np.cross(corners[1] - corners[0], corners[3] - corners[0])
    s = np.linspace(0, circle.length_m, 13)
    assert np.abs((circle.position(s) - centre) @ normal).max() < 1e-9  # in the test plane
    np.testing.assert_allclose(np.linalg.norm(circle.position(s) - centre, axis=1), 0.4 * side, atol=1e-9)


# --- IK along a path --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def singular_line():
    return build_path(PathSpec.model_validate(load_yaml(SAMPLES / "rx130l/paths/line-near-singularity.yaml")))


def test_ik_along_the_line_near_the_wrist_singularity(rx130l, singular_line):
    jp = solve_path_ik(rx130l, singular_line, singular_line.spec.branch)
    assert jp.labels == {"shoulder": "front", "elbow": "up", "wrist": "positive"}
    assert np.all(jp.q[:, 4] > 0)
    assert np.degrees(np.abs(jp.q[:, 4]).min()) == pytest.approx(3.26, abs=0.05)  # architecture §9: ≈ 3.3°
    margin, at = jp.min_sigma_min
    assert at == pytest.approx(0.6, abs=0.01) and 0.005 < margin < 0.05
    assert np.max(np.abs(np.diff(jp.q, axis=0))) <= 0.02 + 1e-12  # continuous branch, small steps
    # The spline reproduces the path between knots and its derivative is J⁻¹·[p'; ω'].
    d = rx130l.create_data()
    s = (jp.sigma[:-1] + jp.sigma[1:]) / 2
    for si in s[::7]:
        pin.framesForwardKinematics(rx130l.model, d, jp(si))
        assert np.linalg.norm(d.oMf[rx130l.tcp_frame_id].translation - singular_line.position([si])[0]) < 1e-7
        jac = pin.computeFrameJacobian(rx130l.model, d, jp(si), rx130l.tcp_frame_id, pin.LOCAL_WORLD_ALIGNED)
        exact = np.linalg.solve(jac, singular_line.twist_rate([si])[0])
        assert np.abs(jp(si, 1) - exact).max() < 2e-3 * max(1.0, np.abs(exact).max())


def test_ik_honours_a_calibrated_model(rx130l, singular_line):
    from rxcomm.model.geometric_errors import ErrorModel

    errors = ErrorModel.from_mapping(rx130l, {"joint_2.tx": 0.002, "joint_3.ry": 0.003, "tool.tz": -0.001})
    calibrated = errors.apply(rx130l)
    jp_nom = solve_path_ik(rx130l, singular_line, singular_line.spec.branch)
    jp_cal = solve_path_ik(calibrated, singular_line, singular_line.spec.branch)
    d = calibrated.create_data()
    for si in np.linspace(0, singular_line.length_m, 5):
        pin.framesForwardKinematics(calibrated.model, d, jp_cal(si))
        assert (
            np.linalg.norm(d.oMf[calibrated.tcp_frame_id].translation - singular_line.position([si])[0])
            < 1e-7
        )
    assert np.abs(jp_cal.q[0] - jp_nom.q[0]).max() > 1e-3  # the correction is real


@pytest.mark.parametrize(
    ("start", "end", "words"),
    [
        ([1.05, -0.6, 0.30], [1.05, 0.6, 0.30], ("singularity", "joint_4 and joint_6", "σ ∈ [0.5")),
        ([1.05, -0.6, 0.35], [2.2, 0.6, 0.35], ("unreachable", "σ ∈ [0.9")),
        ([2.6, -0.6, 0.35], [2.6, 0.6, 0.35], ("start pose is unreachable",)),
    ],
)
def test_ik_names_singular_and_unreachable_stretches(rx130l, start, end, words):
    p = build_path(spec({"type": "line", "start_m": start, "end_m": end}))
    with pytest.raises(InfeasibleError) as e:
        solve_path_ik(rx130l, p, p.spec.branch)
    for w in words:
        assert w in str(e.value)


def test_ik_names_the_joint_at_its_limit(rx130l):
    # A circle around the robot with the tool held: J1 (or J6, turning against it) runs out of range.
    geo = {
        "type": "circle",
        "centre_m": [0, 0, 0.6],
        "normal": [0, 0, 1],
        "radius_m": 1.0,
        "start_direction": [0, -1, 0],
    }
    p = build_path(spec(geo, orientation={"rpy_deg": [180, 0, 0]}))
    with pytest.raises(InfeasibleError, match=r"joint_[16] reaches its limit \[.*\] rad at σ = "):
        solve_path_ik(rx130l, p, p.spec.branch)
