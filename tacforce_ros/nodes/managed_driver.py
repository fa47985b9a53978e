"""Managed (lifecycle) driver nodes: xela_driver, ft_bridge and allegro_driver follow the ROS 2
node lifecycle (design.ros2.org/articles/node_lifecycle.html), so `ros2 lifecycle set` and
lifecycle managers drive them:

* configure (unconfigured -> inactive): open the device link and check the device;
* activate (inactive -> active): publish; the hand's servos on and its joint stream started;
* deactivate (active -> inactive): publish nothing; the hand made safe (zero torque, servos
  off, stream stopped). The XELA and F/T links stay open, so activating again is immediate;
* cleanup (inactive -> unconfigured): close the link;
* shutdown (from any state) does whatever of deactivate and cleanup is due; so does the end of
  the process (SIGINT/SIGTERM), through `leave_safe`.

`autostart` (default true, as the launch files and `session` pass it) configures and activates
at start-up, so the node behaves as a plain driver; a failed transition then ends the process
with the reason: exit code 2 for a device that cannot be opened (as for a bad parameter), 1 for
anything else. With autostart false the node starts unconfigured and waits for its
transitions. A transition that fails logs why and leaves the node where it was (configure:
unconfigured, activate: inactive), as the lifecycle design asks; a deactivate or cleanup that
fails is an error: the device is made safe, its link closed, and the node goes back to
unconfigured. The link's health is on /diagnostics while the node is active (nodes/link_status.py).
"""
from __future__ import annotations

from collections.abc import Callable

from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from tacforce_ros.devices.polling import PollingDriver
from tacforce_ros.nodes.node_base import StopRequested, TacforceNode
from tacforce_ros.nodes.parameters import ParamSpec, ParameterError
from tacforce_ros.nodes.link_status import LinkStatusReporter

AUTOSTART = ParamSpec('autostart', True, 'configure and activate at start-up; false: start '
                      'unconfigured, for `ros2 lifecycle set` or a lifecycle manager')
SUCCESS, FAILURE, ERROR = (TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE,
                           TransitionCallbackReturn.ERROR)


class ManagedDriver(TacforceNode, LifecycleNode):
    """A TacforceNode with the ROS 2 lifecycle. Subclasses implement the four device steps;
    each may raise (ParameterError for what the user must change), which fails the
    transition with its message. Publishers made with create_lifecycle_publisher publish only
    while active; `status` (see report_link) reports the link on /diagnostics while active."""

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        # The device's state, set once a step has succeeded: the lifecycle's own state is a
        # transition state meanwhile, and the device threads read these to gate publishing.
        self.configured = False
        self.active = False
        self.autostarting = False            # the device steps may block only while True
        self.transition_error: Exception | None = None
        self.status: LinkStatusReporter | None = None

    # --- the device steps ------------------------------------------------------------------

    def open_device(self) -> None:
        """configure: open the link, check the device."""

    def start_device(self) -> None:
        """activate: what the device must do before its data is published."""

    def stop_device(self) -> None:
        """deactivate: leave the device safe; the link stays open."""

    def close_device(self) -> None:
        """cleanup: close the link."""

    def report_link(self, link: PollingDriver, hardware_id: str, **reporter_options) -> None:
        """open_device's call for its new link: `status` reports on it (made on the first
        configure with `reporter_options`; counters carry on over later ones)."""
        if self.status is None:
            self.status = LinkStatusReporter(self, link, hardware_id, **reporter_options)
        else:
            self.status.watch(link, hardware_id)

    # --- the lifecycle ---------------------------------------------------------------------

    def _step(self, transition: str, step: Callable[[], None], *, first: bool = True
              ) -> TransitionCallbackReturn:
        """Run one device step; a failure is logged with its reason and, for the step the
        transition is about (`first`), kept as `transition_error`."""
        try:
            step()
        except Exception as exc:     # noqa: BLE001 - a failed transition says why, in the log
            if first:
                self.transition_error = exc
            if isinstance(exc, StopRequested):      # asked to stop meanwhile: no failure
                self.get_logger().info(f'{transition} not done: {exc}')
            else:
                self.get_logger().error(f'{transition} failed: {type(exc).__name__}: {exc}')
            return FAILURE
        return SUCCESS

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.transition_error = None
        if self._step('configure', self.open_device) != SUCCESS:
            self._step('configure (closing what it opened)', self.close_device, first=False)
            return FAILURE          # back to unconfigured
        self.configured = True
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.transition_error = None
        if self._step('activate', self.start_device) != SUCCESS:
            self._step('activate (making the device safe again)', self.stop_device, first=False)
            return FAILURE          # back to inactive
        self.active = True
        if self.status is not None:
            self.status.resume()
        return super().on_activate(state)      # enables the lifecycle publishers

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        # Publishing stops first, whatever the device does; a device that cannot be made safe
        # is an error: on_error then closes its link.
        self.transition_error = None
        super().on_deactivate(state)
        self.active = False
        if self.status is not None:
            self.status.pause('inactive (lifecycle): nothing published')
        return SUCCESS if self._step('deactivate', self.stop_device) == SUCCESS else ERROR

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        # The link is released, or abandoned if closing fails (an error: logged, and on_error
        # finds nothing left to close).
        self.transition_error = None
        result = self._step('cleanup', self.close_device)
        self.configured = False
        super().on_cleanup(state)
        if self.status is not None:
            self.status.log_counters()
        return SUCCESS if result == SUCCESS else ERROR

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        result = SUCCESS
        if self.active:
            result = self.on_deactivate(state)
        if self.configured:
            cleaned = self.on_cleanup(state)
            result = result if result != SUCCESS else cleaned
        return result

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        # A transition returned ERROR, or raised (rclpy then logs nothing): make safe what is
        # open, back to unconfigured.
        self.get_logger().error(f'lifecycle error from {state.label}: making the device safe '
                                'and closing its link')
        if self.active:
            self.active = False
            self._step('error (making the device safe)', self.stop_device, first=False)
        if self.configured:
            self.configured = False
            self._step('error (closing the link)', self.close_device, first=False)
        return SUCCESS

    # --- start and end of the process -------------------------------------------------------

    def on_built(self) -> None:
        if not self.params[AUTOSTART.name]:
            self.get_logger().info('unconfigured: waiting for lifecycle transitions '
                                   f'(ros2 lifecycle set {self.get_fully_qualified_name()} '
                                   'configure)')
            return
        self.autostarting = True
        try:
            for name, transition in (('configure', self.trigger_configure),
                                     ('activate', self.trigger_activate)):
                if transition() != SUCCESS:
                    error = self.transition_error
                    if isinstance(error, (ParameterError, StopRequested)):
                        raise error
                    raise RuntimeError(f'autostart: {name} failed: '
                                       + (f'{type(error).__name__}: {error}' if error
                                          else 'see the log above'))
        finally:
            self.autostarting = False

    def destroy_node(self) -> None:
        super().destroy_node()
        # rclpy's LifecycleNode leaves its state machine, which holds the node, to the garbage
        # collector; the process ends without one (nodes/entry.py), so it is destroyed here and
        # the node leaves the ROS graph now, not when its DDS lease runs out (20 s).
        machine = getattr(self, '_state_machine', None)
        if machine is not None:
            machine.destroy_when_not_in_use()

    def leave_safe(self) -> None:
        if self.configured and self.trigger_shutdown() != SUCCESS:
            raise RuntimeError(f'shutdown: {self.transition_error}')
