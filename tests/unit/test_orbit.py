"""The orbit of `render-uncertainty --views orbit` (splatu.orbit): off-centre cameras, and its circle or arc."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from splatu.data.scene import CameraScene, CameraViews
from splatu.errors import SplatuError
from splatu.orbit import (
    ARC_MARGIN_DEGREES,
    ARC_RADIUS_SCALE,
    CIRCLE_RADIUS_SCALE,
    capture_frame,
    orbit_cameras,
    plan_orbit,
)
from splatu.render_uncertainty import RenderUncertaintyConfig, orbit_note, view_spec
from tests.synthetic_scenes import look_at_camera, ring_cameras


@pytest.mark.parametrize(("row", "col"), [(0, 0), (1, 2), (2, 2)])
def test_an_orbit_of_tiles_looks_at_the_capture_s_centre_from_its_image_s_centre(row, col):
    """Tiles cut from larger photos (a 3x3 grid of 96x72 photos: 32x24 tiles with the photo's K shifted to each) now
    train, with a warning. The orbit copied the first camera's K, principal point and all, so a corner tile's orbit
    put the capture's centre at (-15.7, -12.2) of a 32x24 image: every frame showed a window beside it."""
    tiles = []
    for photo in ring_cameras(6, 96, 72):
        K = photo.K.clone()
        K[0, 2] -= col * 32
        K[1, 2] -= row * 24
        tiles.append(dataclasses.replace(photo, K=K, width=32, height=24))
    centre = capture_frame(tiles).center
    for frame in orbit_cameras(tiles, 4):
        w2c, K = frame.camera.world_to_camera.double(), frame.camera.K.double()
        x, y, z = w2c[:3, :3] @ centre.double() + w2c[:3, 3]
        uv = torch.stack([K[0, 0] * x / z + K[0, 2], K[1, 1] * y / z + K[1, 2]])
        assert float(z) > 0 and torch.allclose(uv, torch.tensor([16.0, 12.0], dtype=torch.float64), atol=1e-3)
        assert (frame.camera.width, frame.camera.height) == (32, 24)
        assert frame.camera.K[0, 0] == tiles[0].K[0, 0] and frame.camera.K[1, 1] == tiles[0].K[1, 1]


@pytest.mark.parametrize("rounding", [0.0, 5e-9])
def test_an_orbit_of_cameras_turning_on_one_spot_is_refused_in_one_line(rounding):
    """Their optical axes meet at their common centre, so the orbit's radius was 0 and every orbit camera sat on the
    point it looked at: an all-zero rotation, views of nothing (coverage 0, U 1) and exit 0. At web-Mercator
    coordinates (2e7) float64 rounding leaves the normalised centres 5e-9 apart, which must count as one spot too."""
    K = np.array([[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])
    spot = np.array([1.0, 2.0, 3.0])
    cameras = [look_at_camera(spot + rounding * np.array([np.sin(3 * a), np.cos(5 * a), a]),
                              spot + np.array([np.cos(a), np.sin(a), 0.1]), K, 32, 24)
               for a in np.linspace(0.0, 1.5, 5)]
    with pytest.raises(SplatuError) as caught:
        orbit_cameras(cameras, 4)
    assert "share one position" in caught.value.what and "--views eval, train or cameras" in caught.value.fix


@pytest.mark.parametrize("count", [2, 5])
def test_an_orbit_of_cameras_that_all_look_one_way_is_refused_in_one_line(count):
    """A stereo pair, or a camera slid along a line, has parallel optical axes, which meet nowhere: the centre was
    the least-squares solution of least norm, the middle of the cameras themselves, and the orbit circled there at half
    their median distance from it, looking sideways along their line at nothing they saw, with exit 0."""
    K = np.array([[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])
    along = np.linspace(-1.0, 1.0, count)
    cameras = [look_at_camera(np.array([x, 0.0, 0.3]), np.array([x, 4.0, 0.3]), K, 32, 24) for x in along]
    with pytest.raises(SplatuError) as caught:
        orbit_cameras(cameras, 4)
    assert "parallel" in caught.value.what and "--views eval, train or cameras" in caught.value.fix
    # axes that converge, however slightly (a forward-facing capture), still meet in front of the cameras
    converging = [look_at_camera(np.array([x, 0.0, 0.3]), np.array([0.0, 40.0, 0.3]), K, 32, 24) for x in along]
    assert float(capture_frame(converging).center[1]) == pytest.approx(40.0)


def _one_sided(n: int = 9, spread_degrees: float = 40.0) -> list:
    """A door photographed from the front: cameras 3 m from it over `spread_degrees` of azimuth about +y, +z up."""
    K = np.array([[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])
    door = np.array([5.0, -2.0, 1.2])
    cameras = []
    for a in np.radians(np.linspace(-0.5 * spread_degrees, 0.5 * spread_degrees, n)):
        eye = door + 3.0 * np.array([np.sin(a), np.cos(a), -0.1])
        cameras.append(look_at_camera(eye, door, K, 32, 24))
    return cameras


def _azimuths_and_distances(orbit, cameras) -> tuple[np.ndarray, np.ndarray]:
    """Each orbit camera's azimuth from the captured side's middle (degrees) and distance to the capture's centre."""
    frame = capture_frame(cameras)
    side = torch.linalg.cross(frame.up, frame.forward_axis)
    offsets = torch.stack([f.camera.center().double() for f in orbit]) - frame.center
    azimuths = torch.rad2deg(torch.atan2(offsets @ side, offsets @ frame.forward_axis))
    return azimuths.numpy(), (offsets.norm(dim=1) / frame.radius).numpy()


def test_a_capture_from_one_side_gets_an_arc_over_that_side_at_the_cameras_distance():
    """The orbit circled every capture at half its radius: behind a door photographed from the front (nothing was
    trained there) and, at half the distance, among the surfaces around it (lund_door, fox)."""
    cameras = _one_sided()
    plan = plan_orbit(cameras)
    assert plan.half_width is not None and math.degrees(plan.cover.width) == pytest.approx(40.0, abs=1e-6)
    orbit = orbit_cameras(cameras, 24)
    azimuths, distances = _azimuths_and_distances(orbit, cameras)
    assert np.allclose(distances, 1.0, atol=1e-9)
    reach = 20.0 + ARC_MARGIN_DEGREES  # half the captured 40°, and the margin past each edge
    assert np.abs(azimuths).max() == pytest.approx(reach, abs=1e-6)
    assert azimuths.max() > 20.0 and azimuths.min() < -20.0  # past both edges of what the capture saw
    elevations = [f.elevation_degrees for f in orbit]
    assert max(elevations) == pytest.approx(50.0) and min(elevations) == pytest.approx(-50.0)


def test_a_ring_and_the_poster_stand_in_keep_the_circle_at_half_the_radius():
    """Captures walked around their subject keep the orbit they had: the poster stand-in's (the main job's output)
    is pinned to the camera centres the orbit gave before the arc existed. (Those differ from run to run by 3e-17:
    torch.linalg.lstsq, which finds the centre, does not round the same way every call.)"""
    from splatu.data.poster import PosterConfig
    from splatu.data.poster.path import camera_path

    path = camera_path(PosterConfig())
    for cameras in (ring_cameras(8, 32, 24), path):
        plan = plan_orbit(cameras)
        assert plan.half_width is None and plan.radius_scale == CIRCLE_RADIUS_SCALE
    orbit = orbit_cameras(path, 24)
    centres = torch.stack([orbit[k].camera.center().double() for k in (0, 6, 12, 18)])
    before = torch.tensor([[0.018235523852307572, 0.4358039678923267, 1.2582120048652707],
                           [-0.7428443389671099, -0.02776472258519342, 0.6839580748688778],
                           [-0.005093001893284953, -0.5276261564106586, 0.10970414487248498],
                           [0.7559868609261325, -0.06405746593313835, 0.6839580748688777]], dtype=torch.float64)
    assert torch.allclose(centres, before, rtol=0.0, atol=1e-12)
    explicit = orbit_cameras(path, 24, radius_scale=CIRCLE_RADIUS_SCALE, shape="circle")
    for auto, given in zip(orbit, explicit, strict=True):
        assert torch.allclose(auto.camera.world_to_camera, given.camera.world_to_camera, rtol=0.0, atol=1e-12)


def test_the_flags_given_win_over_the_layout_s_choice():
    """--orbit-radius-scale and --orbit-shape, when given, are kept whatever the capture's layout would choose."""
    one_sided, ring = _one_sided(), ring_cameras(8, 32, 24)
    azimuths, distances = _azimuths_and_distances(orbit_cameras(one_sided, 24, radius_scale=0.5), one_sided)
    assert np.allclose(distances, 0.5, atol=1e-9) and np.abs(azimuths).max() < 90.0  # the arc, at the given radius
    azimuths, distances = _azimuths_and_distances(orbit_cameras(one_sided, 24, shape="circle"), one_sided)
    assert np.allclose(distances, CIRCLE_RADIUS_SCALE, atol=1e-9) and np.abs(azimuths).max() == pytest.approx(180.0)
    azimuths, distances = _azimuths_and_distances(orbit_cameras(ring, 24, shape="arc"), ring)
    assert np.allclose(distances, ARC_RADIUS_SCALE, atol=1e-9)
    # around the side where most cameras are (any, on an even ring), 90° either side: never from behind it
    assert np.abs(azimuths).max() == pytest.approx(90.0, abs=1e-6)


def test_the_command_says_why_once_when_the_layout_chose_the_arc():
    """The arc replaces the circle without a flag, so the command says why and how to get the circle back."""
    one_sided = _one_sided()

    def note(cameras: list, config: RenderUncertaintyConfig) -> str | None:
        return orbit_note(plan_orbit(cameras, config.orbit_shape, config.orbit_radius_scale), config)

    said = note(one_sided, RenderUncertaintyConfig(views="orbit"))
    assert said is not None and "cover 40° of azimuth" in said and "70° arc" in said
    assert "--orbit-radius-scale 1" in said and "--orbit-shape circle" in said and "\n" not in said
    given = note(one_sided, RenderUncertaintyConfig(views="orbit", orbit_radius_scale=0.7))
    assert given is not None and "--orbit-radius-scale" not in given  # the radius given is not explained
    assert note(one_sided, RenderUncertaintyConfig(views="orbit", orbit_shape="arc")) is None
    assert note(ring_cameras(8, 32, 24), RenderUncertaintyConfig(views="orbit")) is None


def test_the_orbit_record_says_which_path_the_frames_were_taken_on():
    """render.json's record of the orbit: the shape auto chose, its radius and its arc, read after the run."""
    arc = plan_orbit(_one_sided()).record(50.0)
    assert arc["shape"] == "arc" and arc["radius_scale"] == ARC_RADIUS_SCALE and arc["max_elevation_degrees"] == 50.0
    assert arc["covered_azimuth_degrees"] == pytest.approx(40.0) and arc["arc_degrees"] == pytest.approx(70.0)
    circle = plan_orbit(ring_cameras(8, 32, 24)).record(60.0)
    assert circle["shape"] == "circle" and circle["radius_scale"] == CIRCLE_RADIUS_SCALE
    assert circle["arc_degrees"] is None and circle["covered_azimuth_degrees"] > 180.0


@pytest.mark.parametrize(("frames", "limit", "kept"), [(24, 4, [0, 6, 12, 18]), (24, 3, [0, 8, 16]),
                                                       (5, 2, [0, 2])])
def test_max_views_of_an_orbit_spreads_them_round_its_loop(frames, limit, kept):
    """The orbit is a closed loop: its last frame is next to its first, so --max-views 4 of 24 frames took 0, 8, 15
    and 23, two views 15° apart, and --max-views 2 of 5 two neighbours."""
    cameras = ring_cameras(8, 32, 24)
    scene = CameraScene(torch.zeros(3), 1.0, CameraViews(cameras, [c.name for c in cameras]))
    spec = view_spec(scene, "orbit", RenderUncertaintyConfig(views="orbit", orbit_frames=frames, max_views=limit))
    assert spec.names == [f"orbit_{k:03d}" for k in kept]
