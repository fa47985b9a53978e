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
from tacforce_ros.sim.sample import SimSample, StepState, checked_torques
from tacforce_ros.sim.scene import CLOSED_LOOP_FINGER, Scene, SceneError
from tacforce_ros.sim.sensors import TactileSensor
from tacforce_ros.sim.vector import Vec3, add3, cross3, dot3, matTvec3, matvec3, scale3, sub3

FRICTION = 1.0   # silicone skin on PLA / YCB surfaces: grippy; our estimate
# Rotor inertia reflected through the Allegro gearbox, per joint (our estimate); it also keeps
# the explicit contact spring well inside the integrator's stability bound.
ARMATURE = 2e-5  # kg m^2


class ModelBuild:
    """The MuJoCo model under construction, as the 'model' stage effects see and edit it."""

    def __init__(self, spec: mujoco.MjSpec, finger: str, hand_wide: bool = True) -> None:
        self.spec = spec
        self.finger = finger
        # A grasp builds one per finger: effects on every joint of the hand act on the first.
        self.hand_wide = hand_wide
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
        self._driven = (~others).astype(np.float64)   # 1 on the pressing finger's joints
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
        # Single 3-vectors of the step path are tuples of floats (sim/vector.py says why).
        self.offset: Vec3 = tuple(build.contact_offset.tolist())
        self.s0 = self.model.body(self.sensor.array.frame_id).id
        ft = self.model.body(self.hand.rig_frame(self.finger)).id
        # The lab places the rig so the plate just touches the (real) fingertip at the contact
        # pose; the finger starts at its start pose, clear of the plate when the two differ.
        self.data.qpos[:] = self._q(self.contact_pose)
        mujoco.mj_kinematics(self.model, self.data)
        rot = self.data.xmat[self.tip].reshape(3, 3)
        tip_centre = add3(self.data.xpos[self.tip].tolist(), matvec3(rot.tolist(), self.offset))
        self.r_base_f = self.data.xmat[ft].reshape(3, 3).copy()
        self.up: Vec3 = tuple(self.r_base_f[:, 2].tolist())   # plate/object normal, to the finger
        surface = add3(tip_centre, self.up, -self.radius)   # where the tip touches at contact
        obj = self.scene.soft_object
        if obj is None:
            self.plate_centre = add3(surface, self.up, -self.scene.plate.radius)
            self.sensor_origin = surface
        else:
            self.sensor_origin = add3(surface, self.up, -obj.thickness)
        self.surface = surface
        self.obj = obj
        self.obj_x = self.obj_v = 0.0              # object compression and its rate
        self.anchor: Vec3 | None = None            # stick point of the tangential spring
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
        self._s0_rotation = data.xmat[self.s0].reshape(3, 3)   # {S0} -> base; its T: base -> {S0}
        self._s0_position = data.xpos[self.s0]
        self._qpos, self._qvel, self._qfrc_applied = data.qpos, data.qvel, data.qfrc_applied
        self._f_from_base = self.r_base_f.T.tolist()                      # base -> {F}
        self._array_axis = self.sensor.array.rotations[0][:, 0]
        self._last_frame: tuple | None = None

    # ------------------------------------------------------------------ contact

    def contact_point(self) -> np.ndarray:
        """Current contact point on the fingertip sphere, base frame."""
        centre = self._centre()
        return np.array(add3(centre, self._surface(centre)[0], -self.radius))

    def _centre(self) -> Vec3:
        """Centre of the tip sphere, base frame."""
        return add3(self._tip_position.tolist(),
                    matvec3(self._tip_rotation.tolist(), self.offset))

    def _surface(self, centre: Vec3) -> tuple[Vec3, float]:
        """(contact normal, penetration depth) of the tip sphere centred at `centre`."""
        if self.obj is None:
            d = sub3(centre, self.plate_centre)
            distance = math.sqrt(dot3(d, d))
            return scale3(1.0 / distance, d), self.radius - (distance - self.scene.plate.radius)
        return self.up, self.radius - (dot3(sub3(centre, self.surface), self.up) + self.obj_x)

    def _contact_force(self) -> tuple[Vec3, Vec3, bool]:
        """(force on the finger, contact point, active), base frame."""
        centre = self._centre()
        normal, depth = self._surface(centre)
        point = add3(centre, normal, -self.radius)
        if depth <= 0.0:
            self.anchor = None
            return (0.0, 0.0, 0.0), point, False
        mujoco.mj_jac(self.model, self.data, self._jac, None, np.array(point), self.tip)
        velocity = (self._jac @ self._qvel).tolist()
        relative = add3(velocity, self.up, self.obj_v) if self.obj is not None else velocity
        approach = dot3(relative, normal)
        normal_force = max(self.skin_k * depth - self.skin_c * approach, 0.0)
        if self.anchor is None:
            self.anchor = point
        slip = sub3(point, self.anchor)
        slip = add3(slip, normal, -dot3(slip, normal))
        tangential_velocity = add3(relative, normal, -approach)
        tangential = add3(scale3(-self.skin_k, slip), tangential_velocity, -self.skin_c)
        limit = FRICTION * normal_force
        size = math.sqrt(dot3(tangential, tangential))
        if size > limit:   # sliding: the stick point follows so the spring sits on the cone
            tangential = scale3(limit / size, tangential)
            self.anchor = add3(point, tangential, 1.0 / self.skin_k)
        return add3(tangential, normal, normal_force), point, True

    # ------------------------------------------------------------------ step

    def step(self, joint_torques: np.ndarray | None = None) -> SimSample:
        data = self.data
        command = checked_torques(joint_torques)
        t = self.step_index * self.dt
        torque = command * self._driven   # the others: their joint springs
        state = StepState(t=t, contact=None, torque=torque)
        self.pipeline.run('torque', state)
        force, point, active = self._contact_force()
        on_sensor = self._advance_object(force)
        self._qfrc_applied[:] = state.torque
        self._tip_force[:] = force
        self._tip_torque[:] = cross3(sub3(point, self._tip_com.tolist()), force)
        mujoco.mj_step(self.model, data)
        # Ground truth and tactile frame in {S0}: the force the array applies (= -force on it).
        s0_rotation = self._s0_rotation.tolist()
        true_force = np.array(matTvec3(s0_rotation, scale3(-1.0, force)))
        state.q, state.qdot = self._qpos.copy(), self._qvel.copy()
        fresh = self.step_index % self.frame_every == 0
        if fresh:
            # The dynamics' tip sphere only approximates the skin: the sensor sees the contact
            # where the skin is, with the skin's own normal; the force's tilt from it is shear.
            near = matTvec3(s0_rotation, sub3(point, self._s0_position.tolist()))
            point_s0, skin_normal = skin_surface(self._taxel_positions, self._taxel_normals,
                                                 np.array(near))
            state.contact = Contact(true_force, point_s0, skin_normal, self._array_axis, active)
            self.sensor.measure(state)
            self._last_frame = (state.counts_out, state.temperatures, point_s0)
        else:
            state.counts_out, state.temperatures, point_s0 = self._last_frame
        torque_at_sensor = cross3(sub3(point, self.sensor_origin), on_sensor)
        state.wrench = np.array(matvec3(self._f_from_base, on_sensor)
                                + matvec3(self._f_from_base, torque_at_sensor))
        self.pipeline.run('wrench', state)
        self.pipeline.run('delivery', state)
        self.step_index += 1
        return SimSample(t=t + self.dt, taxel_counts=state.counts_out,
                         temperatures=state.temperatures, ft_wrench=state.wrench, ft_status=0,
                         q=state.q, qdot=state.qdot,
                         true_force=true_force, contact_point=point_s0, in_contact=active,
                         delivered=state.delivered, tactile_fresh=fresh)

    def _advance_object(self, force_on_finger: Vec3) -> Vec3:
        """Advance the soft object one step; return the force on the F/T sensor (base frame)."""
        if self.obj is None:   # rigid plate: the sensor carries the contact force
            return scale3(-1.0, force_on_finger)
        obj, dt = self.obj, self.dt
        push = dot3(force_on_finger, self.up)   # the object's push on the finger: its load
        spring = obj.stiffness * self.obj_x + obj.damping * self.obj_v
        # Semi-implicit Euler; the object cannot lift off the sensor (it is taped on).
        self.obj_v += dt * (push - spring) / obj.mass
        self.obj_x = max(self.obj_x + dt * self.obj_v, 0.0)
        if self.obj_x == 0.0:
            self.obj_v = max(self.obj_v, 0.0)
        shear = sub3(scale3(push, self.up), force_on_finger)   # -(f - push up), exactly
        return add3(shear, self.up, -spring)

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
