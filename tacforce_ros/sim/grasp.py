"""Grasp simulator: the thumb and one to three fingers holding a free object, MuJoCo dynamics.

The hand is the URDF compiled by MuJoCo, as in the closed-loop simulator (sim/closed_loop.py),
mounted as the scene's `gravity` says; the grasping fingers take the caller's joint torques and
the others are held by their joint springs. The object is a free body (sphere, box or cylinder,
the scene's `grasp_objects` entry) placed midway between the fingertips at their contact poses,
its grip axis (x) from the other fingers to the thumb. Until `hand_over` s it hangs in a fixture
(a MuJoCo weld to the world: an operator holding it out to the hand); then the fixture lets go
and the fingers alone hold it against gravity.

Contact is the closed-loop simulator's penalty model per fingertip, against the object's surface
instead of a plate: the tip sphere's penetration into the object (signed distance of the shape),
a normal spring-damper, a stick-slip tangential spring bounded by Coulomb friction (the object's
`friction`), with velocities relative to the object's surface point; the force acts on both the
fingertip and the object. A soft object is a spring-damper in series with the skin at each
contact (its `stiffness`, `damping`): the contact yields as both do.

Every fingertip's skin produces its tactile frame from its own contact (one TactileSensor per
grasping fingertip, the object's surface its indenter); the whole-hand frame takes each array's
rows from its own sensor. Ground truth per fingertip: the contact force in that array's {S0},
as the force the array applies to the object. The object's pose gives slip and drops.

Opt-in disturbances (`grasp.disturbances`): a push (a force on the object's centre over a time)
and added mass (the object's mass grows at a time, as when something is put into it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from tacforce_ros.hand.description import HandDescription
from tacforce_ros.sim.closed_loop import ARMATURE, ModelBuild
from tacforce_ros.sim.contact import Contact, skin_surface
from tacforce_ros.sim.effects import Pipeline
from tacforce_ros.sim.operator import FINGER_JOINTS
from tacforce_ros.sim.sample import SimSample, StepState, checked_torques
from tacforce_ros.sim.scene import GraspObject, Scene, SceneError
from tacforce_ros.sim.sensors import TactileSensor
from tacforce_ros.sim.vector import cross

# The contact poses are solved for a tip sphere of the scene's tip_radius (hand/pinch.py); the
# mounted skin's extra thickness (kinematic_mismatch) is what a real hand adds to its nominal
# model, so the object is placed between the simulated tips and may sit this much off.
FIT_TOLERANCE = 0.006     # m
DROP_DISTANCE = 0.02      # m below where it was handed over: the object is dropped


@dataclass
class GraspSample(SimSample):
    """SimSample of a grasp scene; per grasping finger, in the order of scene.grasp['fingers']."""
    finger_forces: dict[str, np.ndarray] | None = None   # N, force each array applies, its {S0}
    finger_forces_base: dict[str, np.ndarray] | None = None   # N, the same in the base frame
    finger_contact: dict[str, bool] | None = None
    contact_points: dict[str, np.ndarray] | None = None  # m, {S0}, at the last tactile frame
    object_position: np.ndarray | None = None            # m, base frame
    object_quaternion: np.ndarray | None = None          # w, x, y, z, base frame
    held_by_fixture: bool = True
    dropped: bool = False


class _Finger:
    """One grasping finger: its sensor, tip body and contact state."""

    def __init__(self, name: str, sensor: TactileSensor) -> None:
        self.name = name
        self.sensor = sensor
        self.joints = FINGER_JOINTS[name]
        self.anchor: np.ndarray | None = None   # stick point, object frame
        self.frame: tuple | None = None         # (counts rows, point_s0) of the last frame
        self.true_force = self.true_force_base = np.zeros(3)
        self.active = False


def signed_distance(obj: GraspObject, point: np.ndarray) -> tuple[float, np.ndarray]:
    """(distance of `point` from the object's surface, negative inside; unit outward normal
    there), both in the object's frame."""
    if obj.shape == 'sphere':
        norm = float(np.linalg.norm(point))
        normal = point / norm if norm > 0.0 else np.array([1.0, 0.0, 0.0])
        return norm - obj.size[0], normal
    if obj.shape == 'box':
        half = np.asarray(obj.size)
        excess = np.abs(point) - half
        outside = np.maximum(excess, 0.0)
        norm = float(np.linalg.norm(outside))
        if norm > 0.0:
            return norm, np.sign(point) * outside / norm
        axis = int(np.argmax(excess))
        normal = np.zeros(3)
        normal[axis] = 1.0 if point[axis] >= 0.0 else -1.0
        return float(excess[axis]), normal
    radius, half_length = obj.size                       # cylinder, axis along z
    radial = float(math.hypot(point[0], point[1]))
    across = np.array([point[0], point[1], 0.0]) / radial if radial > 0.0 else \
        np.array([1.0, 0.0, 0.0])
    excess = np.array([radial - radius, abs(point[2]) - half_length])
    along = np.array([0.0, 0.0, 1.0 if point[2] >= 0.0 else -1.0])
    outside = np.maximum(excess, 0.0)
    norm = float(np.linalg.norm(outside))
    if norm > 0.0:
        return norm, (outside[0] * across + outside[1] * along) / norm
    return (float(excess[0]), across) if excess[0] >= excess[1] else (float(excess[1]), along)


class GraspSimulator:
    """Simulator for scenes of kind 'grasp' (one step = 1/physics_rate s)."""

    def __init__(self, scene: Scene, hand: HandDescription, seed: int | None = None) -> None:
        if scene.kind != 'grasp' or scene.grasp_object is None:
            raise SceneError(f'{scene.name}: not a grasp scene')
        self.scene, self.hand = scene, hand
        self.dt = scene.dt
        self.frame_every = int(round(scene.physics_rate / scene.tactile_rate))
        grasp = scene.grasp
        self.object = scene.grasp_object
        self.fingers = tuple(grasp['fingers'])
        self.finger = self.fingers[0]
        self.contact_pose = {f: np.asarray(grasp['fingers'][f]['contact_pose'], np.float64)
                             for f in self.fingers}
        self.start_pose = {f: np.asarray(grasp['fingers'][f]['pose'], np.float64)
                           for f in self.fingers}
        self.rest = np.asarray(grasp['hand_pose'], np.float64)
        self.gravity = np.asarray(grasp['gravity'], np.float64)
        if not np.linalg.norm(self.gravity) > 0.0:
            raise SceneError(f'{scene.name}: grasp.gravity is zero: the object would not need '
                             'holding, and "up" is not defined')
        self.down = self.gravity / np.linalg.norm(self.gravity)
        self.held_kp, self.held_kd = float(grasp['others_kp']), float(grasp['others_kd'])
        self.tip_radius = float(grasp['tip_radius'])
        skin_k, skin_c = float(grasp['skin_stiffness']), float(grasp['skin_damping'])
        obj = self.object
        # Skin and a soft object's surface in series: both yield under the one contact force.
        self.contact_k = skin_k if obj.stiffness is None else 1.0 / (1.0 / skin_k
                                                                     + 1.0 / obj.stiffness)
        self.contact_c = skin_c if not obj.damping else 1.0 / (1.0 / skin_c + 1.0 / obj.damping)
        self.hand_over = float(grasp['hand_over'])
        self.disturbances = dict(grasp.get('disturbances') or {})
        driven = np.zeros(16, bool)
        for f in self.fingers:
            driven[FINGER_JOINTS[f]] = True
        self._driven = driven.astype(np.float64)
        self.held = np.flatnonzero(~driven)
        # One sensor chain per grasping fingertip, each with the scene's effects; the hand's
        # actuators and links (model, torque and delivery stages) follow the first one's.
        self._fingers = [
            _Finger(f, TactileSensor(hand, f'{f}_tip', obj.plate, Pipeline.from_scene(
                scene.effects), 1.0 / scene.tactile_rate, self.dt)) for f in self.fingers]
        self.pipeline = self._fingers[0].sensor.pipeline
        self.reset(seed)

    # ------------------------------------------------------------------ model

    def _q(self, poses: dict[str, np.ndarray]) -> np.ndarray:
        q = self.rest.copy()
        for finger, pose in poses.items():
            q[FINGER_JOINTS[finger]] = pose
        return q

    def _compile(self, placement: tuple[np.ndarray, np.ndarray] | None = None
                 ) -> tuple[mujoco.MjModel, list[ModelBuild]]:
        """The hand and the object, the object at `placement` (position, quaternion; the
        fixture holds it there) or at the origin."""
        spec = mujoco.MjSpec.from_file(str(self.hand.urdf_path))
        spec.option.timestep = self.dt
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.gravity = self.gravity
        for geom in spec.geoms:
            geom.contype = geom.conaffinity = 0   # contact is our penalty model
        held = {f'joint_{j}.0': j for j in self.held}
        for joint in spec.joints:
            joint.armature = ARMATURE
            if joint.name in held:
                joint.stiffness = np.eye(len(np.atleast_1d(joint.stiffness)))[0] * self.held_kp
                joint.springref = self.rest[held[joint.name]]
                joint.damping = np.eye(len(joint.damping))[0] * self.held_kd
        for body in spec.bodies:
            if body.name.startswith('link_') and int(body.name[5:].split('.')[0]) in self.held:
                body.gravcomp = 1.0
        builds = []
        for number, finger in enumerate(self.fingers):
            build = ModelBuild(spec, finger, hand_wide=number == 0)
            self.pipeline.run('model', build)
            builds.append(build)
        obj = self.object
        body = spec.worldbody.add_body(name='grasp_object')
        if placement is not None:
            body.pos, body.quat = placement
        body.add_freejoint()
        geom_type = {'sphere': mujoco.mjtGeom.mjGEOM_SPHERE, 'box': mujoco.mjtGeom.mjGEOM_BOX,
                     'cylinder': mujoco.mjtGeom.mjGEOM_CYLINDER}[obj.shape]
        size = (list(obj.size) + [0.0, 0.0])[:3]
        # Uniform density: the inertia follows from the shape and the mass.
        body.add_geom(type=geom_type, size=size, mass=obj.mass, contype=0, conaffinity=0)
        # The fixture: a static body where the object is handed over, welded to it at the
        # identity pose (given explicitly: MuJoCo takes an all-zero pose as "as compiled").
        holder = spec.worldbody.add_body(name='grasp_fixture')
        if placement is not None:
            holder.pos, holder.quat = placement
        fixture = spec.add_equality(name='grasp_fixture', type=mujoco.mjtEq.mjEQ_WELD,
                                    objtype=mujoco.mjtObj.mjOBJ_BODY, name1='grasp_object',
                                    name2='grasp_fixture')
        data = np.zeros(len(fixture.data))
        data[6] = data[10] = 1.0      # relative quaternion w; torque scale
        fixture.data = data
        return spec.compile(), builds

    def reset(self, seed: int | None = None) -> None:
        self.seed = self.scene.seed if seed is None else int(seed)
        for finger in self._fingers:
            finger.sensor.reset(self.seed, self.scene.sensor_seed)
        # The simulated tips at their contact poses place the object (a first build), which the
        # fixture then holds where it was built.
        self.model, builds = self._compile()
        self._bind(builds)
        placement = self._placement()
        self.model, builds = self._compile(placement)
        self._bind(builds)
        model, data = self.model, self.data
        self._mass = float(model.body_mass[self.body])
        self._inertia = model.body_inertia[self.body].copy()
        data.qpos[:16] = self._q(self.start_pose)
        data.eq_active[self.weld] = True
        mujoco.mj_forward(model, data)
        self.step_index = 0
        self.fixture = True
        self.dropped = False
        self._added = False
        self._jac = np.zeros((3, model.nv))
        self._jac_object = np.zeros((3, model.nv))

    def _bind(self, builds: list[ModelBuild]) -> None:
        model = self.model
        self.data = mujoco.MjData(model)
        self.body = model.body('grasp_object').id
        self.weld = model.equality('grasp_fixture').id
        for finger, build in zip(self._fingers, builds, strict=True):
            finger.tip = model.body(build.tip_body).id
            finger.radius = self.tip_radius + build.tip_radius_extra
            finger.offset = build.contact_offset.copy()
            finger.s0 = model.body(finger.sensor.array.frame_id).id
            finger.anchor, finger.frame, finger.active = None, None, False
            finger.true_force = finger.true_force_base = np.zeros(3)

    def _placement(self) -> tuple[np.ndarray, np.ndarray]:
        """(position, quaternion) of the object midway between the tips at their contact
        poses, x from the others' tips to the thumb's, z as near up as that allows."""
        model, data = self.model, self.data
        data.qpos[:16] = self._q(self.contact_pose)
        mujoco.mj_kinematics(model, data)
        centres = {f.name: self._centre(f) for f in self._fingers}
        thumb = centres['thumb']
        others = np.mean([c for n, c in centres.items() if n != 'thumb'], axis=0)
        gap = float(np.linalg.norm(thumb - others))
        radius = self._fingers[0].radius
        misfit = gap - 2.0 * radius - self.object.width
        if abs(misfit) > FIT_TOLERANCE:
            raise SceneError(f'{self.scene.name}: the fingertips at their contact poses are '
                             f'{(gap - 2 * radius) * 1e3:.1f} mm apart, the '
                             f'{self.object.name} is {self.object.width * 1e3:.1f} mm across')
        x_axis = (thumb - others) / gap
        up = -self.down
        z_axis = up - (up @ x_axis) * x_axis
        z_axis /= np.linalg.norm(z_axis)
        rotation = np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis])
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, rotation.reshape(-1))
        self.handed_at = 0.5 * (thumb + others)
        return self.handed_at.copy(), quat

    # ------------------------------------------------------------------ contact

    def _centre(self, finger: _Finger) -> np.ndarray:
        """Centre of a fingertip's contact sphere, base frame."""
        rotation = self.data.xmat[finger.tip].reshape(3, 3)
        return self.data.xpos[finger.tip] + rotation @ finger.offset

    def _contact(self, finger: _Finger) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """(force on the fingertip, contact point, contact normal toward the finger, active),
        base frame; the force on the object is its negative."""
        data = self.data
        centre = self._centre(finger)
        rotation = data.xmat[self.body].reshape(3, 3)
        position = data.xpos[self.body]
        local = rotation.T @ (centre - position)
        distance, normal_local = signed_distance(self.object, local)
        normal = rotation @ normal_local
        depth = finger.radius - distance
        point = centre - finger.radius * normal
        if depth <= 0.0:
            finger.anchor = None
            return np.zeros(3), point, normal, False
        mujoco.mj_jac(self.model, data, self._jac, None, point, finger.tip)
        mujoco.mj_jac(self.model, data, self._jac_object, None, point, self.body)
        relative = (self._jac - self._jac_object) @ data.qvel
        approach = float(relative @ normal)
        normal_force = max(self.contact_k * depth - self.contact_c * approach, 0.0)
        if finger.anchor is None:
            finger.anchor = rotation.T @ (point - position)
        anchor = rotation @ finger.anchor + position
        slip = point - anchor
        slip -= (slip @ normal) * normal
        tangential_velocity = relative - approach * normal
        tangential = -self.contact_k * slip - self.contact_c * tangential_velocity
        limit = self.object.friction * normal_force
        size = float(np.linalg.norm(tangential))
        if size > limit:   # sliding: the stick point follows so the spring sits on the cone
            tangential *= limit / size
            finger.anchor = rotation.T @ (point + tangential / self.contact_k - position)
        return tangential + normal_force * normal, point, normal, True

    # ------------------------------------------------------------------ step

    def release(self) -> None:
        """The fixture lets go of the object (also at `hand_over` s by itself)."""
        self.fixture = False
        self.data.eq_active[self.weld] = False

    def step(self, joint_torques: np.ndarray | None = None) -> GraspSample:
        data = self.data
        command = checked_torques(joint_torques)
        t = self.step_index * self.dt
        if self.fixture and t >= self.hand_over:
            self.release()
        self._disturb(t)
        state = StepState(t=t, contact=None, torque=command * self._driven)
        self.pipeline.run('torque', state)
        data.qfrc_applied[:16] = state.torque
        data.xfrc_applied[:] = 0.0
        object_com = data.xipos[self.body]
        contacts = []
        for finger in self._fingers:
            force, point, normal, active = self._contact(finger)
            tip_com = data.xipos[finger.tip]
            data.xfrc_applied[finger.tip, :3] += force
            data.xfrc_applied[finger.tip, 3:] += cross(point - tip_com, force)
            data.xfrc_applied[self.body, :3] -= force
            data.xfrc_applied[self.body, 3:] -= cross(point - object_com, force)
            contacts.append((force, point, normal, active))
        push = self.disturbances.get('push')
        if push and push['at'] <= t < push['at'] + push['duration']:
            data.xfrc_applied[self.body, :3] += np.asarray(push['force'], np.float64)
        mujoco.mj_step(self.model, data)
        fresh = self.step_index % self.frame_every == 0
        counts = None
        for finger, (force, point, normal, active) in zip(self._fingers, contacts, strict=True):
            s0_rotation = data.xmat[finger.s0].reshape(3, 3)
            finger.true_force = s0_rotation.T @ -force
            finger.true_force_base = -force
            finger.active = active
            if fresh:
                near = s0_rotation.T @ (point - data.xpos[finger.s0])
                array = finger.sensor.array
                point_s0, skin_normal = skin_surface(array.positions, array.rotations[:, :, 2],
                                                     near)
                axis = s0_rotation.T @ data.xmat[self.body].reshape(3, 3)[:, 2] \
                    if self.object.shape == 'cylinder' else array.rotations[0][:, 0]
                axis = axis - (axis @ skin_normal) * skin_normal
                axis_norm = np.linalg.norm(axis)
                axis = axis / axis_norm if axis_norm > 1e-9 else array.rotations[0][:, 0]
                finger_state = StepState(t=t, contact=Contact(finger.true_force, point_s0,
                                                              skin_normal, axis, active))
                finger.sensor.measure(finger_state)
                frame = finger_state.counts_out
                if counts is None:   # the whole hand's frame: the first finger's sensor ...
                    counts, temperatures = frame.copy(), finger_state.temperatures
                rows = array.flat_indices
                counts[rows] = frame[rows]      # ... each array's rows from its own
                finger.frame = (frame[rows], point_s0)
        if fresh:
            self._last_frame = (counts, temperatures)
        state.counts_out, state.temperatures = self._last_frame
        first = self._fingers[0]
        state.q, state.qdot = data.qpos[:16].copy(), data.qvel[:16].copy()
        state.wrench = np.zeros(6)          # no F/T sensor in a grasp: the fingertips hold it
        self.pipeline.run('delivery', state)
        position = data.xpos[self.body].copy()
        below = float((position - self.handed_at) @ self.down)
        self.dropped = self.dropped or (not self.fixture and below > DROP_DISTANCE)
        self.step_index += 1
        return GraspSample(
            t=t + self.dt, taxel_counts=state.counts_out, temperatures=state.temperatures,
            ft_wrench=state.wrench, ft_status=0, q=state.q, qdot=state.qdot,
            true_force=first.true_force.copy(), contact_point=first.frame[1],
            in_contact=first.active, delivered=state.delivered, tactile_fresh=fresh,
            finger_forces={f.name: f.true_force.copy() for f in self._fingers},
            finger_forces_base={f.name: f.true_force_base.copy() for f in self._fingers},
            finger_contact={f.name: f.active for f in self._fingers},
            contact_points={f.name: f.frame[1] for f in self._fingers},
            object_position=position, object_quaternion=data.xquat[self.body].copy(),
            held_by_fixture=self.fixture, dropped=self.dropped)

    def _disturb(self, t: float) -> None:
        added = self.disturbances.get('added_mass')
        if added and not self._added and t >= added['at']:
            self._added = True
            scale = (self._mass + added['mass']) / self._mass
            self.model.body_mass[self.body] = self._mass * scale
            self.model.body_inertia[self.body] = self._inertia * scale
