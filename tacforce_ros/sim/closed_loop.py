"""Closed-loop simulator: MuJoCo finger dynamics from the hand URDF, torques in, contact out.

The hand is the URDF compiled by MuJoCo (its own collision geometry switched off). One finger
takes the caller's joint torques; the others are held by their own PD in the simulation. The
fingertip touches the scene's plate (a rigid spherical indenter on the F/T sensor) or a soft
object taped to the sensor. Contact is an explicit penalty model evaluated each physics step:
normal spring-damper of the skin, a stick-slip tangential spring bounded by Coulomb friction;
a soft object is a mass on a spring-damper (its compliance and damping) between the contact and
the sensor, so the F/T reading is NOT collocated with the fingertip force during transients.
A tactile frame is produced every 1/tactile_rate s (SimSample.tactile_fresh).
"""
from __future__ import annotations

import math

import mujoco
import numpy as np

from tacforce_ros.hand.description import HandDescription
from tacforce_ros.sim.contact import Contact, skin_surface
from tacforce_ros.sim.effects import Pipeline
from tacforce_ros.sim.operator import FINGER_JOINTS
from tacforce_ros.sim.sample import SimSample, StepState
from tacforce_ros.sim.scene import CLOSED_LOOP_FINGER, Scene, SceneError
from tacforce_ros.sim.sensors import TactileSensor

FRICTION = 1.0   # silicone skin on PLA / YCB surfaces: grippy; our estimate
# Rotor inertia reflected through the Allegro gearbox, per joint (our estimate); it also keeps
# the explicit contact spring well inside the integrator's stability bound.
ARMATURE = 2e-5  # kg m^2


class ModelBuild:
    """The MuJoCo model under construction, as the 'model' stage effects see and edit it."""

    def __init__(self, spec: mujoco.MjSpec, finger: str) -> None:
        self.spec = spec
        first = 4 * list(FINGER_JOINTS).index(finger)
        self.tip_body = f'link_{first + 3}.0_tip'
        self._finger_bodies = [f'link_{first + k}.0' for k in range(4)] + [self.tip_body]
        self.tip_radius_extra = 0.0
        self.contact_offset = np.zeros(3)   # contact sphere centre in the tip link frame

    def hand_joints(self) -> list:
        return list(self.spec.joints)

    def finger_bodies(self) -> list:
        """The finger's bodies from its base link to the tip, as MjSpec bodies."""
        return [self.spec.body(name) for name in self._finger_bodies]


class ClosedLoopSimulator:
    """Simulator for scenes of kind 'closed_loop' (one step = 1/physics_rate s)."""

    def __init__(self, scene: Scene, hand: HandDescription, seed: int | None = None) -> None:
        self.scene, self.hand = scene, hand
        self.dt = scene.dt
        self.frame_every = int(round(scene.physics_rate / scene.tactile_rate))
        finger = scene.finger
        self.finger = finger.get('name', CLOSED_LOOP_FINGER)
        if hand.array(scene.array).finger != self.finger:
            raise SceneError(f'{scene.name}: array {scene.array} is not on the pressing finger '
                             f'({self.finger}); the closed loop estimates its own fingertip')
        self.joints = FINGER_JOINTS[self.finger]
        self.pose = np.asarray(finger['pose'], np.float64)          # start pose
        self.contact_pose = np.asarray(finger.get('contact_pose', finger['pose']), np.float64)
        others = np.ones(16, bool)
        others[self.joints] = False
        self.held = np.flatnonzero(others)
        self.held_pose = np.asarray(finger['others'], np.float64)
        self.held_kp, self.held_kd = float(finger['others_kp']), float(finger['others_kd'])
        self.tip_radius = float(finger['tip_radius'])
        self.skin_k, self.skin_c = float(finger['skin_stiffness']), float(finger['skin_damping'])
        self.pipeline = Pipeline.from_scene(scene.effects)
        self.sensor = TactileSensor(hand, scene.array, scene.plate, self.pipeline,
                                    1.0 / scene.tactile_rate, self.dt)
        self._taxel_positions = self.sensor.array.positions
        self._taxel_normals = self.sensor.array.rotations[:, :, 2]
        self.reset(seed)

    # ------------------------------------------------------------------ model

    def _q(self, finger_pose: np.ndarray) -> np.ndarray:
        q = np.empty(16)
        q[self.joints] = finger_pose
        q[self.held] = self.held_pose
        return q

    def _compile(self) -> tuple[mujoco.MjModel, ModelBuild]:
        spec = mujoco.MjSpec.from_file(str(self.hand.urdf_path))
        spec.option.timestep = self.dt
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        for geom in spec.geoms:
            geom.contype = geom.conaffinity = 0   # contact is our penalty model
        held = {f'joint_{j}.0' for j in self.held}
        for joint in spec.joints:
            joint.armature = ARMATURE
            if joint.name in held:
                # Held fingers: a joint spring-damper towards their pose, which the implicit
                # integrator treats stably, plus MuJoCo's exact gravity compensation.
                index = int(joint.name.split('_')[1].split('.')[0])
                joint.stiffness = np.eye(len(np.atleast_1d(joint.stiffness)))[0] * self.held_kp
                joint.springref = self.held_pose[list(self.held).index(index)]
                joint.damping = np.eye(len(joint.damping))[0] * self.held_kd
        for body in spec.bodies:
            if body.name.startswith('link_') and int(body.name[5:].split('.')[0]) in self.held:
                body.gravcomp = 1.0
        build = ModelBuild(spec, self.finger)
        self.pipeline.run('model', build)
        return spec.compile(), build

    def reset(self, seed: int | None = None) -> None:
        self.seed = self.scene.seed if seed is None else int(seed)
        self.sensor.reset(self.seed, self.scene.sensor_seed)
        self.model, build = self._compile()
        self.data = mujoco.MjData(self.model)
        self.tip = self.model.body(build.tip_body).id
        self.radius = self.tip_radius + build.tip_radius_extra
        self.offset = build.contact_offset
        self.s0 = self.model.body(self.sensor.array.frame_id).id
        ft = self.model.body(self.hand.rig_frame(self.finger)).id
        # The lab places the rig so the plate just touches the (real) fingertip at the contact
        # pose; the finger starts at its start pose, clear of the plate when the two differ.
        self.data.qpos[:] = self._q(self.contact_pose)
        mujoco.mj_kinematics(self.model, self.data)
        rot = self.data.xmat[self.tip].reshape(3, 3)
        tip_centre = self.data.xpos[self.tip] + rot @ self.offset
        self.r_base_f = self.data.xmat[ft].reshape(3, 3).copy()
        self.up = self.r_base_f[:, 2]          # plate/object surface normal, towards the finger
        surface = tip_centre - self.radius * self.up   # where the tip touches at contact pose
        obj = self.scene.soft_object
        if obj is None:
            self.plate_centre = surface - self.scene.plate.radius * self.up
            self.sensor_origin = surface
        else:
            self.sensor_origin = surface - obj.thickness * self.up
        self.surface = surface
        self.obj = obj
        self.obj_x = self.obj_v = 0.0              # object compression and its rate
        self.anchor: np.ndarray | None = None      # stick point of the tangential spring
        self.data.qpos[:] = self._q(self.pose)
        mujoco.mj_forward(self.model, self.data)
        self.step_index = 0
        self._jac = np.zeros((3, self.model.nv))
        # Views into MjData's buffers, made once per model: they follow every step.
        data = self.data
        self._tip_rotation = data.xmat[self.tip].reshape(3, 3)
        self._tip_position, self._tip_com = data.xpos[self.tip], data.xipos[self.tip]
        self._tip_force, self._tip_torque = (data.xfrc_applied[self.tip, :3],
                                             data.xfrc_applied[self.tip, 3:])
        self._s0_from_base = data.xmat[self.s0].reshape(3, 3).T   # rotates base -> {S0}
        self._s0_position = data.xpos[self.s0]
        self._qpos, self._qvel, self._qfrc_applied = data.qpos, data.qvel, data.qfrc_applied
        self._f_from_base = self.r_base_f.T                           # base -> {F}
        self._last_frame: tuple | None = None

    # ------------------------------------------------------------------ contact

    def contact_point(self) -> np.ndarray:
        """Current contact point on the fingertip sphere, base frame."""
        centre = self._tip_position + self._tip_rotation @ self.offset
        return centre - self.radius * self._surface(centre)[0]

    def _surface(self, centre: np.ndarray) -> tuple[np.ndarray, float]:
        """(contact normal, penetration depth) of the tip sphere centred at `centre`."""
        if self.obj is None:
            d = centre - self.plate_centre
            distance = math.sqrt(d @ d)
            return d / distance, self.radius - (distance - self.scene.plate.radius)
        return self.up, self.radius - ((centre - self.surface) @ self.up + self.obj_x)

    def _contact_force(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """(force on the finger, contact point, normal, active), base frame."""
        centre = self._tip_position + self._tip_rotation @ self.offset
        normal, depth = self._surface(centre)
        point = centre - self.radius * normal
        if depth <= 0.0:
            self.anchor = None
            return np.zeros(3), point, normal, False
        mujoco.mj_jac(self.model, self.data, self._jac, None, point, self.tip)
        velocity = self._jac @ self._qvel
        relative = velocity + self.obj_v * self.up if self.obj is not None else velocity
        approach = relative @ normal
        normal_force = max(self.skin_k * depth - self.skin_c * approach, 0.0)
        if self.anchor is None:
            self.anchor = point.copy()
        slip = point - self.anchor
        slip -= (slip @ normal) * normal
        tangential_velocity = relative - approach * normal
        tangential = -self.skin_k * slip - self.skin_c * tangential_velocity
        limit = FRICTION * normal_force
        size = math.sqrt(tangential @ tangential)
        if size > limit:   # sliding: the stick point follows so the spring sits on the cone
            tangential *= limit / size
            self.anchor = point + tangential / self.skin_k
        return normal_force * normal + tangential, point, normal, True

    # ------------------------------------------------------------------ step

    def step(self, joint_torques: np.ndarray | None = None) -> SimSample:
        data = self.data
        command = np.zeros(16) if joint_torques is None else np.asarray(joint_torques, np.float64)
        if command.shape != (16,) or not np.isfinite(command).all():
            raise ValueError('joint_torques must be 16 finite values (N m), Allegro order')
        t = self.step_index * self.dt
        torque = np.zeros(16)   # the others: their joint springs
        torque[self.joints] = command[self.joints]
        state = StepState(t=t, contact=None, torque=torque)
        self.pipeline.run('torque', state)
        force, point, normal, active = self._contact_force()
        on_sensor = self._advance_object(force, normal)
        self._qfrc_applied[:] = state.torque
        self._tip_force[:] = force
        mujoco.mju_cross(self._tip_torque, point - self._tip_com, force)
        mujoco.mj_step(self.model, data)
        # Ground truth and tactile frame in {S0}: the force the array applies (= -force on it).
        true_force = self._s0_from_base @ -force
        state.q, state.qdot = self._qpos.copy(), self._qvel.copy()
        fresh = self.step_index % self.frame_every == 0
        if fresh:
            # The dynamics' tip sphere only approximates the skin: the sensor sees the contact
            # where the skin is, with the skin's own normal; the force's tilt from it is shear.
            point_s0, skin_normal = skin_surface(self._taxel_positions, self._taxel_normals,
                                                 self._s0_from_base @ (point - self._s0_position))
            state.contact = Contact(true_force, point_s0, skin_normal,
                                    self.sensor.array.rotations[0][:, 0], active)
            self.sensor.measure(state)
            self._last_frame = (state.counts_out, state.temperatures, point_s0)
        else:
            state.counts_out, state.temperatures, point_s0 = self._last_frame
        torque_at_sensor = np.empty(3)
        mujoco.mju_cross(torque_at_sensor, point - self.sensor_origin, on_sensor)
        wrench = state.wrench = np.empty(6)
        np.matmul(self._f_from_base, on_sensor, out=wrench[:3])
        np.matmul(self._f_from_base, torque_at_sensor, out=wrench[3:])
        self.pipeline.run('wrench', state)
        self.pipeline.run('delivery', state)
        self.step_index += 1
        return SimSample(t=t + self.dt, taxel_counts=state.counts_out,
                         temperatures=state.temperatures, ft_wrench=state.wrench, ft_status=0,
                         q=state.q, qdot=state.qdot,
                         true_force=true_force, contact_point=point_s0, in_contact=active,
                         delivered=state.delivered, tactile_fresh=fresh)

    def _advance_object(self, force_on_finger: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """Advance the soft object one step; return the force on the F/T sensor (base frame)."""
        if self.obj is None:
            return -force_on_finger          # rigid plate: the sensor carries the contact force
        obj, dt = self.obj, self.dt
        push = float(force_on_finger @ self.up)   # the object's push on the finger: its load
        spring = obj.stiffness * self.obj_x + obj.damping * self.obj_v
        # Semi-implicit Euler; the object cannot lift off the sensor (it is taped on).
        self.obj_v += dt * (push - spring) / obj.mass
        self.obj_x = max(self.obj_x + dt * self.obj_v, 0.0)
        if self.obj_x == 0.0:
            self.obj_v = max(self.obj_v, 0.0)
        shear = push * self.up - force_on_finger   # -(f - push up), exactly
        return -spring * self.up + shear

    # ------------------------------------------------------------------ exact model access

    def exact_jacobian(self) -> np.ndarray:
        """(3, 4) translation Jacobian of the current contact point, base frame, from the
        SIMULATED hand (with its model errors): what a perfect controller would use."""
        jac = np.zeros((3, self.model.nv))
        mujoco.mj_jac(self.model, self.data, jac, None, self.contact_point(), self.tip)
        return jac[:, self.joints]

    def bias_torques(self) -> np.ndarray:
        """(16,) gravity and velocity torques of the simulated hand at its current state."""
        return self.data.qfrc_bias.copy()
