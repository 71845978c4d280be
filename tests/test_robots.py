"""Robot loading: MuJoCo and Pinocchio agree on kinematics and inertias; scene, actuation, generic files, errors."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from robots import BUILTIN_ROBOTS, Kinematics, RobotError, RobotModel, load_robot

ASSETS = Path(__file__).resolve().parent.parent / "assets"
N_CONFIGS = 20


@pytest.fixture(scope="module")
def robots() -> dict[str, RobotModel]:
    return {name: load_robot(name) for name in BUILTIN_ROBOTS}


def _random_configs(robot: RobotModel, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(robot.q_min, robot.q_max, (N_CONFIGS, robot.n))


def _mj_tool(robot: RobotModel, data: mujoco.MjData, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MuJoCo's site position (3,), rotation (3, 3) and [jacp; jacr] (6, n) at q, arm columns in Pinocchio order."""
    model = robot.mj_model
    data.qpos[robot.mj_qpos_adr] = q
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    site = model.site(robot.mj_ee_site).id
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jacp, jacr, site)
    return data.site_xpos[site].copy(), data.site_xmat[site].reshape(3, 3).copy(), \
        np.vstack([jacp, jacr])[:, robot.mj_dof_adr]


def _max_kinematic_gap(robot: RobotModel, configs: np.ndarray) -> float:
    kin, data, gap = Kinematics(robot), mujoco.MjData(robot.mj_model), 0.0
    for q in configs:
        pos, rot, jac = _mj_tool(robot, data, q)
        kin.update(q)
        gap = max(gap, np.abs(kin.ee_position() - pos).max(), np.abs(kin.ee_rotation() - rot).max(),
                  np.abs(kin.ee_jacobian() - jac).max())
    return gap


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_fk_rotation_and_jacobian_match_mujoco(robots: dict[str, RobotModel], name: str) -> None:
    robot = robots[name]
    assert _max_kinematic_gap(robot, _random_configs(robot)) < 1e-9


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_mass_matrix_gravity_and_mass_match_mujoco(robots: dict[str, RobotModel], name: str) -> None:
    """M(q) (armature included) and gravity torques g(q) agree, so every link mass/COM/inertia agrees."""
    robot = robots[name]
    model, data = robot.mj_model, mujoco.MjData(robot.mj_model)
    pdata = robot.pin_model.createData()
    idx = np.ix_(robot.mj_dof_adr, robot.mj_dof_adr)
    for q in _random_configs(robot, seed=1):
        data.qpos[robot.mj_qpos_adr] = q
        data.qvel[:] = 0.0
        mujoco.mj_forward(model, data)
        mass = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, mass)
        pin_mass = pin.crba(robot.pin_model, pdata, q)
        pin_mass = np.triu(pin_mass) + np.triu(pin_mass, 1).T
        assert np.abs(mass[idx] - pin_mass).max() < 1e-9
        gravity = pin.computeGeneralizedGravity(robot.pin_model, pdata, q)
        assert np.abs(data.qfrc_bias[robot.mj_dof_adr] - gravity).max() < 1e-9
    pin_total = sum(inertia.mass for inertia in robot.pin_model.inertias)
    assert model.body_subtreemass[0] == pytest.approx(pin_total, abs=1e-12)
    np.testing.assert_allclose(model.dof_armature[robot.mj_dof_adr], robot.pin_model.armature, atol=0)


def test_panda_inertias_are_the_urdf_values(robots: dict[str, RobotModel]) -> None:
    """MuJoCo kept the URDF's link1 inertia (no balancing): its principal moments are those of the URDF tensor."""
    model = robots["panda"].mj_model
    urdf_tensor = np.array([[0.70337, -0.000139, 0.006772], [-0.000139, 0.70661, 0.019169],
                            [0.006772, 0.019169, 0.009117]])
    link1 = model.body("panda_link1").id
    assert model.body_mass[link1] == pytest.approx(4.970684, abs=1e-12)
    np.testing.assert_allclose(np.sort(model.body_inertia[link1]), np.linalg.eigvalsh(urdf_tensor), atol=1e-12)


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_position_servos_hold_and_settle_at_home(robots: dict[str, RobotModel], name: str) -> None:
    robot = robots[name]
    model = robot.mj_model
    data = mujoco.MjData(model)
    data.qpos[robot.mj_qpos_adr] = robot.q_home
    data.ctrl[robot.mj_actuator_ids] = robot.q_home
    for _ in range(500):  # 1 s at 2 ms
        mujoco.mj_step(model, data)
    assert np.abs(data.qpos[robot.mj_qpos_adr] - robot.q_home).max() < 1e-6
    data.qpos[robot.mj_qpos_adr] = robot.q_home + 0.05  # step response from a 0.05 rad offset on every joint
    data.qvel[:] = 0.0
    for _ in range(500):
        mujoco.mj_step(model, data)
    assert np.all(np.isfinite(data.qpos))
    assert np.abs(data.qpos[robot.mj_qpos_adr] - robot.q_home).max() < 1e-4
    assert np.abs(data.qvel).max() < 1e-3


def test_torque_actuation_holds_with_pinocchio_gravity() -> None:
    robot = load_robot("panda", actuation="torque")
    model, data = robot.mj_model, mujoco.MjData(robot.mj_model)
    pdata = robot.pin_model.createData()
    assert model.body_gravcomp.max() == 0.0
    np.testing.assert_allclose(model.actuator_ctrlrange[robot.mj_actuator_ids, 1], [87] * 4 + [12] * 3)
    data.qpos[robot.mj_qpos_adr] = robot.q_home
    for _ in range(500):
        data.ctrl[robot.mj_actuator_ids] = pin.computeGeneralizedGravity(robot.pin_model, pdata,
                                                                       data.qpos[robot.mj_qpos_adr])
        mujoco.mj_step(model, data)
    assert np.abs(data.qpos[robot.mj_qpos_adr] - robot.q_home).max() < 1e-9


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_scene_xml_round_trips_exactly(robots: dict[str, RobotModel], name: str) -> None:
    robot = robots[name]
    model = mujoco.MjModel.from_xml_string(robot.mjcf_xml, robot.mj_assets)
    for field in ("body_pos", "body_quat", "body_ipos", "body_iquat", "body_mass", "body_inertia", "site_pos"):
        np.testing.assert_array_equal(getattr(model, field), getattr(robot.mj_model, field))
    assert model.camera("workspace").id >= 0 and model.geom("floor").id >= 0
    assert model.opt.timestep == 0.002 and model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert [model.actuator(int(a)).name for a in robot.mj_actuator_ids] == [f"act_{j}" for j in robot.arm_joints]
    assert model.body_gravcomp[1:].min() == 1.0
    assert all(model.jnt_actgravcomp[model.joint(j).id] for j in robot.arm_joints)
    np.testing.assert_allclose(model.actuator_ctrlrange[robot.mj_actuator_ids], np.c_[robot.q_min, robot.q_max])
    assert np.all(robot.q_min < robot.q_home) and np.all(robot.q_home < robot.q_max)


def test_panda_tool_frame_fingers_and_limits(robots: dict[str, RobotModel]) -> None:
    robot = robots["panda"]
    assert robot.ee_frame == "panda_hand_tcp" and robot.n == 7 and not robot.planar
    assert "panda_finger_joint1" not in robot.arm_joints and robot.mj_model.njnt == 7
    np.testing.assert_allclose(robot.v_max, [2.175] * 4 + [2.61] * 3)
    np.testing.assert_allclose(robot.q_max[3], -0.0698)
    data = mujoco.MjData(robot.mj_model)
    data.qpos[robot.mj_qpos_adr] = robot.q_home
    mujoco.mj_kinematics(robot.mj_model, data)
    hand = robot.mj_model.body("panda_hand").id
    tcp = data.xpos[hand] + 0.1034 * data.xmat[hand].reshape(3, 3)[:, 2]
    np.testing.assert_allclose(data.site_xpos[robot.mj_model.site(robot.mj_ee_site).id], tcp, atol=1e-12)
    left = robot.mj_model.body("panda_leftfinger").id  # locked closed, as in Pinocchio's reduced model
    np.testing.assert_allclose(robot.mj_model.body_pos[left], [0.0, 0.0, 0.0584], atol=1e-15)


def test_planar_arm_moves_in_a_horizontal_plane(robots: dict[str, RobotModel]) -> None:
    robot = robots["planar"]
    assert robot.planar and robot.n == 3 and robot.ee_frame == "ee" and robot.mj_ee_site == "ee"
    kin = Kinematics(robot)
    for q in _random_configs(robot):
        kin.update(q)
        assert kin.ee_position()[2] == pytest.approx(0.12, abs=1e-12)
        assert np.abs(kin.ee_jacobian()[2:5]).max() < 1e-12


def test_mjcf_path_loads_like_the_builtin(robots: dict[str, RobotModel], tmp_path: Path) -> None:
    path = tmp_path / "my_arm.xml"
    shutil.copy(ASSETS / "planar_arm.xml", path)
    robot = load_robot(str(path), ee_frame="ee")
    builtin = robots["planar"]
    assert robot.name == "my_arm" and robot.planar and robot.arm_joints == builtin.arm_joints
    kin, ref = Kinematics(robot), Kinematics(builtin)
    for q in _random_configs(robot):
        kin.update(q)
        ref.update(q)
        np.testing.assert_allclose(kin.ee_jacobian(), ref.ee_jacobian(), atol=1e-15)
    assert _max_kinematic_gap(robot, _random_configs(robot)) < 1e-9
    # auto home: well conditioned (x, y Jacobian far from singular) and inside the limits
    ref.update(robot.q_home)
    assert np.linalg.svd(ref.ee_jacobian()[:2], compute_uv=False)[-1] > 0.2
    assert np.all(robot.q_min < robot.q_home) and np.all(robot.q_home < robot.q_max)


def _write_stl_box(path: Path, half: float) -> None:
    """Binary STL of an axis-aligned cube (12 triangles)."""
    corners = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)])
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
             (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    out = bytearray(b"\0" * 80) + struct.pack("<I", len(faces))
    for face in faces:
        out += struct.pack("<3f", 0, 0, 0) + b"".join(struct.pack("<3f", *corners[i]) for i in face) + b"\0\0"
    path.write_bytes(bytes(out))


_URDF = """<?xml version="1.0"?>
<robot name="tri">
  <link name="base"><inertial><mass value="2.0"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>
  </inertial><collision><geometry><mesh filename="package://tri_description/meshes/base.stl"/></geometry></collision>
  </link>
  <link name="l1"><inertial><origin xyz="0 0 0.1" rpy="0.1 0.2 0.3"/><mass value="1.5"/>
    <inertia ixx="0.02" ixy="0.001" ixz="0" iyy="0.018" iyz="0.0005" izz="0.004"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.15 0 0"/><mass value="1.0"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><origin xyz="0.15 0 0"/><geometry><box size="0.3 0.04 0.04"/></geometry></collision></link>
  <link name="l3"><inertial><origin xyz="0.1 0 0"/><mass value="0.5"/>
    <inertia ixx="0.0005" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.002"/></inertial></link>
  <link name="tool"/>
  <joint name="yaw" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/><limit lower="-2.5" upper="2.5" effort="40" velocity="1.5"/></joint>
  <joint name="shoulder" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0.25" rpy="0.3 -0.2 0.1"/><axis xyz="0 1 0"/>
    <limit lower="-1.6" upper="1.6" effort="40" velocity="1.5"/></joint>
  <joint name="elbow" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2.2" upper="2.2" effort="20" velocity="2.0"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="l3"/><child link="tool"/><origin xyz="0.2 0 0" rpy="0 1.2 0"/>
  </joint>
</robot>
"""


def test_urdf_path_with_package_mesh(tmp_path: Path) -> None:
    package = tmp_path / "tri_description"
    (package / "meshes").mkdir(parents=True)
    (package / "urdf").mkdir()
    _write_stl_box(package / "meshes" / "base.stl", 0.05)
    path = package / "urdf" / "tri.urdf"
    path.write_text(_URDF)
    robot = load_robot(str(path), ee_frame="tool")
    assert robot.arm_joints == ("yaw", "shoulder", "elbow") and not robot.planar
    assert set(robot.mj_assets) == {"base.stl"}
    np.testing.assert_allclose(robot.v_max, [1.5, 1.5, 2.0])
    assert robot.mj_ee_site == "ee" and robot.mj_model.site("ee").bodyid == robot.mj_model.body("tool").id
    assert _max_kinematic_gap(robot, _random_configs(robot)) < 1e-9
    data, pdata = mujoco.MjData(robot.mj_model), robot.pin_model.createData()
    for q in _random_configs(robot, seed=2):
        data.qpos[robot.mj_qpos_adr] = q
        mujoco.mj_forward(robot.mj_model, data)
        mass = np.zeros((3, 3))
        mujoco.mj_fullM(robot.mj_model, data, mass)
        pin_mass = pin.crba(robot.pin_model, pdata, q)
        assert np.abs(mass - (np.triu(pin_mass) + np.triu(pin_mass, 1).T)).max() < 1e-9
    with pytest.raises(RobotError, match=r"unknown end-effector frame 'hand'; frames: universe, base, .*tool"):
        load_robot(str(path), ee_frame="hand")


_MJCF = """<mujoco model="two_link">
  <compiler angle="degree" meshdir="parts" inertiafromgeom="false"/>
  <asset><mesh name="cube" file="cube.stl"/></asset>
  <worldbody>
    <body name="base"><inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
      <geom type="mesh" mesh="cube"/>
      <body name="upper" pos="0 0 0.3" euler="0 0 30">
        <joint name="shoulder" axis="0 1 0" range="-90 90"/>
        <inertial pos="0 0 0.15" mass="1.2" fullinertia="0.012 0.012 0.003 0.0005 0.0001 0.0002"/>
        <body name="fore" pos="0 0 0.3" euler="10 0 0">
          <joint name="elbow" axis="0 1 0" range="-120 120"/>
          <inertial pos="0 0 0.12" mass="0.7" diaginertia="0.004 0.004 0.001"/>
          <body name="hand" pos="0 0 0.25" euler="0 20 0">
            <joint name="wrist" axis="1 0 0" range="-150 150"/>
            <inertial pos="0 0 0.03" mass="0.3" diaginertia="0.0005 0.0005 0.0003"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_mjcf_path_with_mesh_and_degrees(tmp_path: Path) -> None:
    (tmp_path / "parts").mkdir()
    _write_stl_box(tmp_path / "parts" / "cube.stl", 0.06)
    path = tmp_path / "two_link.xml"
    path.write_text(_MJCF)
    robot = load_robot(str(path), ee_frame="hand")
    assert robot.arm_joints == ("shoulder", "elbow", "wrist") and not robot.planar
    assert set(robot.mj_assets) == {"cube.stl"}
    np.testing.assert_allclose(robot.q_max, np.deg2rad([90, 120, 150]), atol=1e-12)
    assert _max_kinematic_gap(robot, _random_configs(robot)) < 1e-9
    data = mujoco.MjData(robot.mj_model)
    data.qpos[robot.mj_qpos_adr] = robot.q_home
    mujoco.mj_forward(robot.mj_model, data)
    gravity = pin.computeGeneralizedGravity(robot.pin_model, robot.pin_model.createData(), robot.q_home)
    assert np.abs(data.qfrc_bias[robot.mj_dof_adr] - gravity).max() < 1e-9


@pytest.mark.parametrize(("spec", "kwargs", "message"), [
    ("kuka", {}, r"^unknown robot 'kuka'; built-in: planar, panda, or a path to \.urdf/\.xml$"),
    ("/no/such/arm.urdf", {"ee_frame": "tool"}, r"^robot file not found: /no/such/arm\.urdf$"),
    (str(ASSETS / "planar_arm.xml"), {}, r"needs an end-effector frame \(ee_frame=\.\.\.\)$"),
    ("planar", {"ee_frame": "tip"}, r"^unknown end-effector frame 'tip'; frames: universe, base, joint1, link1, "
                                     r"joint2, link2, joint3, link3, ee$"),
    ("planar", {"actuation": "velocity"}, r"^unknown actuation 'velocity'; known: position, torque$"),
    ("planar", {"ee_frame": "base"}, r"^end-effector frame 'base' is not moved by any arm joint$"),
])
def test_errors_are_one_line_robot_errors(spec: str, kwargs: dict[str, str], message: str) -> None:
    with pytest.raises(RobotError, match=message) as info:
        load_robot(spec, **kwargs)
    assert "\n" not in str(info.value)


def test_unreadable_file_is_a_robot_error(tmp_path: Path) -> None:
    path = tmp_path / "broken.urdf"
    path.write_text("<robot name='x'><link name='a'>")
    with pytest.raises(RobotError, match=r"^cannot parse URDF"):
        load_robot(str(path), ee_frame="a")


def test_continuous_joint_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "wheel.urdf"
    urdf = _URDF.replace('type="revolute"><parent link="base"/>', 'type="continuous"><parent link="base"/>')
    path.write_text(urdf.replace('<mesh filename="package://tri_description/meshes/base.stl"/>', '<box size="1 1 1"/>'))
    with pytest.raises(RobotError, match=r"joint 'yaw' of .* is a JointModelRUBZ: arm joints must be 1-DoF"):
        load_robot(str(path), ee_frame="tool")


# ---------------------------------------------------------------- visual meshes (robots.visual)
def test_panda_draws_its_converted_visual_meshes_and_collides_with_its_collision_meshes(
        robots: dict[str, RobotModel]) -> None:
    from robots.visual import COLLISION_GROUP, VISUAL_GROUP

    model = robots["panda"].mj_model
    visual = [g for g in range(model.ngeom) if model.geom_group[g] == VISUAL_GROUP]
    arm = [g for g in range(model.ngeom) if model.geom_bodyid[g] > 0]
    assert len(visual) >= 10                                            # every link, several colours each
    assert all(model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0 for g in visual)
    collision = [g for g in arm if g not in visual]
    assert collision and all(model.geom_group[g] == COLLISION_GROUP and model.geom_contype[g] for g in collision)
    links = {model.body(model.geom_bodyid[g]).name for g in visual}
    assert {f"panda_link{i}" for i in range(8)} | {"panda_hand"} <= links
    colours = {tuple(np.round(model.mat_rgba[model.geom_matid[g]], 2)) for g in visual}
    assert len(colours) >= 3                                            # white, dark grey, ... kept
    lo, hi = [], []
    for g in visual:                                                    # metres, like the collision meshes
        if model.geom_dataid[g] >= 0:
            m = model.geom_dataid[g]
            v = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
            lo.append(v.min(0))
            hi.append(v.max(0))
    assert 0.05 < float(np.max(np.array(hi) - np.array(lo))) < 0.5


def test_visuals_change_no_dynamics_and_can_be_turned_off(robots: dict[str, RobotModel]) -> None:
    from robots.visual import VISUAL_GROUP

    plain = load_robot("panda", visuals=False)
    model = robots["panda"].mj_model
    for field in ("body_mass", "body_inertia", "body_ipos", "body_pos"):
        np.testing.assert_array_equal(getattr(model, field), getattr(plain.mj_model, field))
    m = plain.mj_model
    assert not any(m.geom_group[g] == VISUAL_GROUP for g in range(m.ngeom))
    link_colours = {tuple(m.geom_rgba[g]) for g in range(m.ngeom) if m.geom_bodyid[g] > 0}
    assert len(link_colours) >= 5                                       # a colour per link


def test_conversion_is_cached_atomically_in_the_user_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from robots import loader, visual

    monkeypatch.setenv("LFD_ROBOTS_CACHE", str(tmp_path / "cache"))
    dae = loader._example_robot_data() / "robots" / "panda_description" / "meshes" / "visual" / "finger.dae"
    parts = visual.convert_mesh(dae)
    files = list((tmp_path / "cache").iterdir())
    assert len(files) == 1 and files[0].suffix == ".npz" and not any(f.name.startswith(".") for f in files)
    assert len(parts) == 2 and all(p[0][:5] != b"solid" for p in parts)  # binary STL per colour
    assert visual.convert_mesh(dae) == parts                            # read back from the cache
    (tmp_path / "bad.dae").write_text("<not collada")
    with pytest.raises(ValueError, match="unreadable mesh"):
        visual.convert_mesh(tmp_path / "bad.dae")


def test_urdf_with_unreadable_visual_falls_back_to_coloured_collision(tmp_path: Path) -> None:
    package = tmp_path / "tri_description"
    (package / "meshes").mkdir(parents=True)
    (package / "urdf").mkdir()
    _write_stl_box(package / "meshes" / "base.stl", 0.05)
    (package / "meshes" / "broken.dae").write_text("<nope")
    text = _URDF.replace('<link name="l3">', '<link name="l3"><visual><geometry><box size="0.2 0.03 0.03"/>'
                         '</geometry><material name="red"><color rgba="1 0 0 1"/></material></visual>')
    text = text.replace('</inertial><collision><geometry><mesh filename="package://tri_description/meshes/base.stl"/>',
                        '</inertial><visual><geometry><mesh filename="package://tri_description/meshes/broken.dae"/>'
                        '</geometry></visual><collision><geometry>'
                        '<mesh filename="package://tri_description/meshes/base.stl"/>')
    path = package / "urdf" / "tri.urdf"
    path.write_text(text)
    with pytest.warns(RuntimeWarning, match="1 link.*collision meshes.*base"):
        robot = load_robot(str(path), ee_frame="tool")
    m = robot.mj_model
    l3 = [g for g in range(m.ngeom) if m.geom_bodyid[g] == m.body("l3").id]
    assert len(l3) == 1 and m.geom_group[l3[0]] == 2 and m.geom_contype[l3[0]] == 0
    np.testing.assert_allclose(m.mat_rgba[m.geom_matid[l3[0]]], [1, 0, 0, 1])
    base = [g for g in range(m.ngeom) if m.geom_bodyid[g] == m.body("base").id]
    assert base and all(m.geom_group[g] == 0 and m.geom_contype[g] for g in base)   # drawn, colliding


def test_table_option_adds_a_table_under_the_robot() -> None:
    robot = load_robot("planar", table=True)
    m = robot.mj_model
    top = m.geom("table_top").id
    assert m.geom_pos[top][2] + m.geom_size[top][2] == pytest.approx(0.0)
    assert m.geom_pos[m.geom("floor").id][2] < -0.5
