"""`tkujax view`: the replay viewer's geometry, poses, selection and overlays as pure functions,
then the page itself on a tiny MuJoCo C sweep: served by viser and driven from a headless
Chromium (Selenium), whose time slider moves the robots (skipped without a Chromium)."""

import io
import shutil
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest

from tkujax.cli import main
from tkujax.viewer.scene_meshes import (com_positions, geom_poses, geom_shapes, mat_to_wxyz,
                                        primitive_mesh)
from tkujax.viewer.playback import (PushScene, Selection, capture_points, frame_index,
                                    in_azimuth_band, parse_band, push_arrow, push_label,
                                    replay_scenes, row_offsets, select_records, step_target)

TWO_PUSHES = """
[sweep]
name = "viewer"
seed = 0
chunk_size = 2
duration_s = 0.9
control = ["on"]

[push.grid]
impulse_ns = [0.8, 3.5]
azimuth_deg = [0]
onset_s = [0.3]
"""

SHAPES_XML = """
<mujoco>
  <asset>
    <material name="blue" rgba="0 0 1 1"/>
    <mesh name="tet" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="base" pos="0 0 0.5">
      <freejoint/>
      <geom name="box" type="box" size="0.1 0.2 0.3" material="blue"/>
      <geom name="ball" type="sphere" size="0.05" pos="0 0 0.4" rgba="1 0 0 1"/>
      <geom name="hidden" type="sphere" size="0.05" group="3"/>
      <body name="arm" pos="0.2 0 0">
        <joint name="hinge" type="hinge" axis="0 1 0"/>
        <geom name="capsule" type="capsule" size="0.03 0.1" pos="0.1 0 0"/>
        <geom name="cylinder" type="cylinder" size="0.04 0.05" pos="0 0.1 0"/>
        <geom name="ellipsoid" type="ellipsoid" size="0.03 0.04 0.05" pos="0 -0.1 0"/>
        <geom name="tet" type="mesh" mesh="tet" pos="0 0 -0.2"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _volume(v, f) -> float:
    """Signed volume of a closed triangle mesh (positive: faces wound outward)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6.0)


@pytest.mark.parametrize("kind,size,volume", [
    ("box", (0.1, 0.2, 0.3), 8 * 0.1 * 0.2 * 0.3),
    ("sphere", (0.05, 0, 0), 4 / 3 * np.pi * 0.05 ** 3),
    ("ellipsoid", (0.03, 0.04, 0.05), 4 / 3 * np.pi * 0.03 * 0.04 * 0.05),
    ("capsule", (0.03, 0.1, 0), np.pi * 0.03 ** 2 * 0.2 + 4 / 3 * np.pi * 0.03 ** 3),
    ("cylinder", (0.04, 0.05, 0), np.pi * 0.04 ** 2 * 0.1),
])
def test_primitive_meshes_enclose_their_volume_outward(kind, size, volume):
    v, f = primitive_mesh(kind, np.array(size, float))
    assert f.min() >= 0 and f.max() < len(v)
    assert _volume(v, f) == pytest.approx(volume, rel=0.12)        # 16-gon facets, outward
    extent = {"box": size, "sphere": (size[0],) * 3, "ellipsoid": size,
              "capsule": (size[0], size[0], size[0] + size[1]),
              "cylinder": (size[0], size[0], size[1])}[kind]
    assert np.allclose(np.abs(v).max(0), extent)


@pytest.fixture(scope="module")
def shapes_model():
    return mujoco.MjModel.from_xml_string(SHAPES_XML)


def test_drawn_geoms_kinds_colours_and_mesh(shapes_model):
    shapes = {s.name: s for s in geom_shapes(shapes_model)}
    assert set(shapes) == {"box", "ball", "capsule", "cylinder", "ellipsoid", "tet"}   # no plane
    assert shapes["box"].rgba == (0.0, 0.0, 1.0, 1.0)                               # material
    assert shapes["ball"].rgba == (1.0, 0.0, 0.0, 1.0)
    assert shapes["tet"].kind == "mesh" and len(shapes["tet"].faces) == 4
    assert [s.name for s in geom_shapes(shapes_model, groups=(3,))] == ["hidden"]
    assert abs(_volume(shapes["tet"].vertices, shapes["tet"].faces)) == pytest.approx(
        0.1 ** 3 / 6, rel=1e-4)


def test_poses_and_com_follow_mujoco_kinematics(shapes_model):
    m = shapes_model
    data = mujoco.MjData(m)
    qpos = np.stack([m.qpos0, m.qpos0.copy()])
    qpos[1, :3] += (0.3, -0.2, 0.1)
    qpos[1, 3:7] = (np.cos(0.3), 0.0, 0.0, np.sin(0.3))        # yaw 0.6 rad
    qpos[1, 7] = 0.8                                             # the hinge
    geoms = [s.geom for s in geom_shapes(m)]
    pos, wxyz = geom_poses(m, qpos, geoms)
    com = com_positions(m, qpos)
    for t in range(2):
        data.qpos[:] = qpos[t]
        mujoco.mj_forward(m, data)
        assert np.allclose(pos[t], data.geom_xpos[geoms])
        assert np.allclose(wxyz[t], mat_to_wxyz(data.geom_xmat[geoms]))
        assert np.allclose(com[t], data.subtree_com[0])
    mat = np.empty(9)
    mujoco.mju_quat2Mat(mat, wxyz[1, 0])
    assert np.allclose(mat, data.geom_xmat[geoms[0]])
    assert not np.allclose(pos[0], pos[1])


def test_capture_point_is_the_lip_one_or_the_recorded_one():
    t = np.arange(1, 11) * 0.03
    com = np.stack([0.1 + 0.2 * t, -0.05 * t, np.full_like(t, 0.25)], 1)
    cp = capture_points(com, t, 9.81)
    omega = np.sqrt(9.81 / 0.25)
    assert np.allclose(cp[:, 0], com[:, 0] + 0.2 / omega)
    assert np.allclose(cp[:, 1], com[:, 1] - 0.05 / omega) and np.all(cp[:, 2] == 0)
    recorded = np.ones((10, 2))
    assert np.array_equal(capture_points(com, t, 9.81, recorded)[:, :2], recorded)


def test_arrow_target_offsets_and_frames():
    arrow = push_arrow(90.0, np.array([1.0, 2.0, 0.3]), 0.2)        # from the right: toward +y
    assert np.allclose(arrow, [[1.0, 1.8, 0.3], [1.0, 2.0, 0.3]])
    ankles = np.array([[0.0, -0.05, 0.03], [0.0, 0.05, 0.03]])      # right, left
    assert step_target(0.0, 0.0, ankles, 0.0) is None
    assert np.allclose(step_target(0.04, 0.0, ankles, 0.0), [0.04, 0.05, 0.0])     # left swings
    assert np.allclose(step_target(0.0, -0.03, ankles, 0.0), [0.0, -0.08, 0.0])    # right
    assert np.allclose(step_target(0.04, 0.0, ankles, np.pi / 2), [0.0, 0.09, 0.0])
    assert np.allclose(row_offsets(3, 0.8)[:, 1], [0.8, 0.0, -0.8])
    t = np.arange(1, 6) * 0.03
    assert [frame_index(t, x) for x in (0.0, 0.03, 0.059, 0.06, 9.0)] == [0, 0, 0, 1, 4]


def test_label_names_the_push_and_a_replay_that_differs():
    stored = dict(impulse_ns=1.2, azimuth_deg=-90.0, fell=True, diverged=False, control=True)
    assert push_label(3, stored) == "#3 1.20 N·s @ 270°\ncontrol on: fell"
    assert push_label(3, stored, dict(fell=False, diverged=False)).endswith("(replayed: survived)")


RECORDS = dict(push_id=np.arange(8), impulse_ns=np.array([0.5, 1, 1.5, 2, 2.5, 3, 3.5, 4.0]),
               azimuth_deg=np.array([0, 90, 180, 270, 350, 10, 45, 315.0]),
               fell=np.array([0, 0, 1, 1, 0, 1, 1, 1], bool),
               diverged=np.array([0, 0, 0, 0, 0, 0, 0, 1], bool),
               control=np.array([1, 0, 1, 0, 1, 0, 1, 0], bool))


@pytest.mark.parametrize("sel,ids", [
    (Selection(max_pushes=8), list(range(8))),
    (Selection(fell=True, max_pushes=8), [2, 3, 5, 6]),          # diverged 7 left out
    (Selection(fell=False, max_pushes=8), [0, 1, 4]),
    (Selection(direction=(315, 45), max_pushes=8), [0, 4, 5, 6, 7]),
    (Selection(direction=(80, 190), impulse=(1.0, 1.5), max_pushes=8), [1, 2]),
    (Selection(control=True, max_pushes=8), [0, 2, 4, 6]),
    (Selection(indices=(6, 1, 3), fell=True), [6, 3]),
    (Selection(max_pushes=3), [0, 4, 7]),                         # spread, ends included
])
def test_records_are_selected_by_the_filters(sel, ids):
    assert select_records(RECORDS, sel) == ids


def test_bad_selections_are_named():
    assert in_azimuth_band(np.array([359.0, 1.0, 180.0]), -10, 10).tolist() == [True, True, False]
    assert parse_band("315,45", "--direction") == (315.0, 45.0)
    with pytest.raises(ValueError, match="--impulse must be LO,HI"):
        parse_band("1", "--impulse")
    with pytest.raises(ValueError, match="--index 9: no such record"):
        select_records(RECORDS, Selection(indices=(9,)))


def test_view_command_refuses_bad_options(tmp_path, capsys):
    assert main(["view", str(tmp_path), "--direction", "a,b"]) == 2
    assert "--direction must be LO,HI" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        main(["view", str(tmp_path), "--fell", "--survived"])
    assert stop.value.code == 2
    assert main(["view", str(tmp_path), "--geom-groups", "0,7"]) == 2
    assert "--geom-groups must be MuJoCo geom groups in [0, 5]" in capsys.readouterr().err


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("viewer")
    spec = root / "two.toml"
    spec.write_text(TWO_PUSHES)
    assert main(["sweep", str(spec), "--out", str(root / "two"), "--backend", "mujoco"]) == 0
    return root / "two"


@pytest.fixture(scope="module")
def scenes(sweep_dir) -> list[PushScene]:
    return replay_scenes(sweep_dir, [0, 1])


def test_replayed_scenes_show_the_records(scenes):
    survived, fell = scenes
    assert survived.label.endswith("survived") and fell.label.endswith(": fell")
    assert survived.offset[1] > 0 > fell.offset[1] and survived.offset[0] == 0
    assert survived.positions.shape == (30, len(survived.shapes), 3)
    assert 0.5 < survived.height_m < 0.6                                 # TKU-X: 56 cm
    assert fell.positions[-1, :, 2].max() < 0.5 * fell.height_m            # lying down
    for s in scenes:                                                       # from behind: +x
        d = s.arrow[1] - s.arrow[0]
        assert d[0] > 0 and abs(d[1]) < 1e-9 and s.arrow[1, 2] == pytest.approx(0.36)
    ratio = np.linalg.norm(np.diff(fell.arrow, axis=0)) / np.linalg.norm(
        np.diff(survived.arrow, axis=0))
    assert ratio == pytest.approx(3.5 / 0.8)
    assert survived.step_target is not None                  # the controller stepped
    assert survived.step_target[0] > survived.positions[0, :, 0].min()
    before, after = survived.frame(0.25), survived.frame(0.45)
    assert not before["arrow_visible"] and after["arrow_visible"] and after["target_visible"]
    assert not np.allclose(fell.frame(0.1)["positions"], fell.frame(0.8)["positions"])


def test_view_command_serves_and_stops(sweep_dir, capsys):
    pytest.importorskip("viser")
    assert main(["view", str(sweep_dir), "--port", "0", "--serve-s", "0", "--survived"]) == 0
    out = capsys.readouterr().out
    assert "#0 0.80 N·s @ 0°, control on: survived" in out and "serving 1 replays at" in out


def _browser():
    """A headless Chromium through Selenium and chromedriver, or a skip naming what is missing."""
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    binary = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")
                   if shutil.which(n)), None)
    driver = shutil.which("chromedriver")
    if binary is None or driver is None:
        pytest.skip("no Chromium and chromedriver found (apt-get install chromium "
                    "chromium-driver)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = binary
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                "--window-size=900,600", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"):
        opts.add_argument(arg)
    return webdriver.Chrome(service=Service(driver), options=opts)


def _wait(cond, timeout_s: float, what: str):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        value = cond()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def _click(browser, label: str) -> None:
    """Click the page's button reading `label` once it shows (React may redraw it meanwhile)."""
    from selenium.common.exceptions import WebDriverException
    from selenium.webdriver.common.by import By

    def attempt():
        try:
            browser.find_element(By.XPATH, f"//button[normalize-space()='{label}']").click()
            return True
        except WebDriverException:
            return False

    _wait(attempt, 10, f"a {label} button to click")


def _screenshot(browser) -> bytes:
    """A PNG of the page; a software renderer busy past chromedriver's wait gets two more tries."""
    from selenium.common.exceptions import TimeoutException

    for _ in range(2):
        try:
            return browser.get_screenshot_as_png()
        except TimeoutException:
            pass
    return browser.get_screenshot_as_png()


def _scene_pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)
    h, w = img.shape[:2]
    return img[h // 3:, : w // 2]                           # the 3D view, below the panels


def test_browser_slider_moves_the_robots(scenes):
    pytest.importorskip("viser")
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    from tkujax.viewer.server import ReplayViewer

    viewer = ReplayViewer(scenes, port=0)                  # any free port
    browser = None
    try:
        browser = _browser()
        browser.get(viewer.url)
        _wait(viewer.server.get_clients, 30, "the page to connect")
        slider = _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "[role=slider]"), 30,
                       "the time slider")[0]
        time.sleep(2.0)                                     # the first frames drawn
        first = _scene_pixels(_screenshot(browser))
        assert np.ptp(first.reshape(-1, 3), axis=0).max() > 60        # not a blank page
        start = [h.position.copy() for h in viewer.geoms[1]]
        slider.send_keys(Keys.END)
        _wait(lambda: viewer.time_s == pytest.approx(float(scenes[0].t[-1])), 20,
              "the browser's slider to reach the end")
        assert viewer.slider.value == pytest.approx(float(scenes[0].t[-1]))
        end = [h.position.copy() for h in viewer.geoms[1]]
        assert np.allclose(end, scenes[1].positions[-1]) and not np.allclose(start, end)
        time.sleep(1.5)
        last = _scene_pixels(_screenshot(browser))
        assert np.mean(np.any(first != last, axis=-1)) > 0.002     # the robots moved on screen
        _click(browser, "Play")
        _wait(lambda: viewer.time_s < float(scenes[0].t[-1]), 20, "playing to loop to the start")
        assert viewer.play.label == "Pause"
        _click(browser, "Pause")
        _wait(lambda: viewer.play.label == "Play", 10, "the pause")
        paused = viewer.time_s
        time.sleep(0.3)
        assert viewer.time_s == paused
    finally:
        if browser is not None:
            browser.quit()
        viewer.stop()


def test_replay_refuses_an_unknown_backend(sweep_dir):
    from tkujax.sweeps.replay import replay

    with pytest.raises(ValueError, match="backend must be 'mujoco' or 'mjx'"):
        replay(sweep_dir, 0, backend="gpu")
