"""The ROS 2 node: depth frames in, obstacle cloud and ground-plane costmap out."""

from __future__ import annotations

import collections
import functools
import sys
import threading
import time
from pathlib import Path
from typing import Any

import rclpy
import rclpy.logging
import rclpy.utilities
from nav_msgs.msg import OccupancyGrid, Odometry
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.time import Time as RclpyTime
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2
from std_msgs.msg import Float64, String

from obstacle_detection.pipeline import jit as jit_support
from .conversions import (
    costmap_to_occupancy_grid,
    result_to_messages,
)
from . import frame_gate, rvl
from .config import DEPTH_TRANSPORT_TOPICS, NodeConfig, build_config, release_memory
from .diagnostics import Context as DiagnosticsContext
from .frame_gate import CameraState as _CameraState
from .frame_gate import stamp_ns as _stamp_ns
from obstacle_detection.viz.overlay import render_overlay
from .diagnostics import (COMPILED, USE_FQN_PARAMETER, HealthWindow, health_status,
                          status_name)
from obstacle_detection.pipeline.fusion import FusedGrid, PoseBuffer
from obstacle_detection.pipeline.geometry import yaw_from_quaternion
from .mount_check import MountCheck
from .mount_source import MountSource
from obstacle_detection.pipeline.params import Intrinsics
from . import RosInputError
from .parameters import (ALL_PARAMS, NODE_NAME, PARAMS_FILE_KEY, check_params_file,
                         params_file_problems, params_files_in_args)


def _qos(depth: int, *, reliable: bool = True, latched: bool = False) -> QoSProfile:
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=(ReliabilityPolicy.RELIABLE if reliable
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                                  else DurabilityPolicy.VOLATILE))


#: Minimum interval between two warnings about the same kind of bad input [s].
WARN_THROTTLE_S = 5.0
#: Minimum interval between two log lines saying the mount disagrees with the floor [s].
MOUNT_WARN_THROTTLE_S = 60.0
#: Outputs, and the inputs with reliable_input: reliable, depth 5.
_RELIABLE_QOS = _qos(5)
#: ~/status and the OccupancyGrids: latched, depth 1 (as map_server), so a late subscriber
#: (RViz's map display) still gets the last state or grid.
_LATCHED_QOS = _qos(1, latched=True)
#: /diagnostics: reliable, as diagnostic_updater publishes it, once a second.
_DIAGNOSTICS_QOS = _qos(10)
#: depth_transport -> (message type, topic): image_transport's names for the depth stream.
DEPTH_TRANSPORTS = {name: (Image if name == 'raw' else CompressedImage, topic)
                    for name, topic in DEPTH_TRANSPORT_TOPICS.items()}
#: Odometry: best effort, which reliable and best-effort publishers both match.
_ODOM_QOS = _qos(20, reliable=False)
#: Depth frames that may wait for the worker (see FrameMailbox): one may wait behind another.
MAILBOX_FRAMES = 2
#: Output key (as result_to_messages names it) -> message type, topic, parameter switching it on.
OUTPUTS = {
    'obstacles': (PointCloud2, 'obstacles/points', None),
    'costmap': (OccupancyGrid, 'obstacles/costmap', None),
    'ground': (PointCloud2, 'obstacles/ground_points', 'publish_ground'),
    'clearing': (PointCloud2, 'obstacles/clearing_points', 'publish_clearing'),
    'marking': (PointCloud2, 'obstacles/marking_points', 'publish_clearing'),
    'overlay': (Image, 'obstacles/overlay', 'publish_overlay'),
    'fused': (OccupancyGrid, 'obstacles/fused_costmap', 'fuse'),
}


class FrameMailbox:
    """The newest ``capacity`` items, oldest taken first: ``put`` drops the oldest when full."""

    def __init__(self, capacity: int) -> None:
        self._cond = threading.Condition()
        self._items: collections.deque = collections.deque(maxlen=capacity)
        self._closed = False

    def put(self, item: Any) -> bool:
        """Store ``item`` as the newest; True if the oldest waiting item was dropped for it."""
        with self._cond:
            dropped = len(self._items) == self._items.maxlen
            self._items.append(item)   # a full deque drops its oldest item
            self._cond.notify()
        return dropped

    def take(self, timeout: float | None = None) -> Any:
        """Remove and return the oldest item, waiting up to ``timeout`` s; None if none/closed."""
        with self._cond:
            self._cond.wait_for(lambda: self._items or self._closed, timeout)
            return self._items.popleft() if self._items and not self._closed else None

    def close(self) -> None:
        """Make every ``take``, waiting or to come, return None."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class DetectorNode(Node):
    """Subscribes to a depth camera, runs the pipeline, publishes obstacles and a costmap."""

    def __init__(self, *, tf_buffer: Any = None, **kwargs: Any) -> None:
        """Declare the parameters, build the detector, subscribe; ``tf_buffer``: a tf2 stand-in."""
        super().__init__(NODE_NAME, **kwargs)
        for spec in ALL_PARAMS:
            self.declare_parameter(spec.name, spec.default, spec.descriptor())
        try:
            self._config = build_config(self._parameter_values())
            self._mount_source = self._make_mount_source(tf_buffer)
        except ValueError:
            self.destroy_node()
            raise
        self.stats = HealthWindow(readers=('diagnostics', 'log'))
        self._mailbox = FrameMailbox(MAILBOX_FRAMES)
        self._mount_said = ''
        self._tf_mount: Any = None   # the last mount TF gave
        self._image_frame = ''       # the frame_id of the last frame processed
        self._mount_check = MountCheck()
        self._cameras: collections.deque[_CameraState] = collections.deque(
            maxlen=frame_gate.CAMERA_INFO_HISTORY)
        self._warn_loggers: dict[str, Any] = {}

        self._status_pub = self.create_publisher(String, '~/status', _LATCHED_QOS)
        # Compiling (a minute) or loading the kernels runs on a thread of its own; frames take
        # the numpy path meanwhile (same results), so no frame waits for it.
        self._cache_filled = jit_support.cache_filled()   # load (a second) or compile?
        self._compile = jit_support.compile_in_background(self._warm_up,
                                                          on_done=self._on_compiled)
        reliable = bool(self.get_parameter('reliable_input').value)
        in_qos = _RELIABLE_QOS if reliable else qos_profile_sensor_data
        # What is switched off is neither advertised nor subscribed.
        self._pubs = {
            key: self.create_publisher(kind, topic,
                                       _LATCHED_QOS if kind is OccupancyGrid else _RELIABLE_QOS)
            for key, (kind, topic, switch) in OUTPUTS.items()
            if switch is None or self.get_parameter(switch).value}
        self._odom_sub: Any = None
        if self._config.fusion is not None:
            self._odom_sub = self.create_subscription(
                Odometry, str(self.get_parameter('odom_topic').value), self._on_odometry,
                _ODOM_QOS)
        self._time_pub = self.create_publisher(Float64, '~/processing_time_ms', _RELIABLE_QOS)
        self._poses = PoseBuffer()
        self._fused: FusedGrid | None = None

        stats_period_s = float(self.get_parameter('stats_period_s').value)
        if stats_period_s > 0.0:
            self.create_timer(stats_period_s, self._log_stats)
        self._started = time.monotonic()
        use_fqn = self.declare_parameter(USE_FQN_PARAMETER, False, ParameterDescriptor(
            description="diagnostic_updater's: name the /diagnostics status after the node's "
                        'fully qualified name, not its name', read_only=True)).value
        self._diagnostics_name = status_name(
            self.get_fully_qualified_name() if use_fqn else self.get_name())
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics',
                                                      _DIAGNOSTICS_QOS)
        self.create_timer(1.0, self.publish_diagnostics)
        self.add_on_set_parameters_callback(self._validate_parameters)
        for service in self.services:   # rclpy's set services raise on an unknown value type
            if service.srv_name.endswith(('/set_parameters', '/set_parameters_atomically')):
                service.callback = functools.partial(self._refuse_unknown_types, service.callback)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self._worker = threading.Thread(target=self._work, name='obstacle_detector_worker',
                                        daemon=True)
        self._worker.start()
        # Subscribe last: a publisher that sees the match finds a node able to process.
        transport = str(self.get_parameter('depth_transport').value)
        depth_type, depth_topic = DEPTH_TRANSPORTS[transport]
        self._depth_sub = self.create_subscription(depth_type, depth_topic, self._on_depth,
                                                   in_qos)
        self._info_sub = self.create_subscription(CameraInfo, 'depth/camera_info',
                                                  self._on_camera_info, in_qos)
        self.get_logger().info(
            f'ready: {self._depth_sub.topic_name} -> '
            f'{", ".join(pub.topic_name for pub in self._pubs.values())}; {self.compute_path()}')
        self._publish_status()

    # -- start-up: compiled kernels -----------------------------------------------------------
    def compute_path(self) -> str:
        """Say which code processes the frames now (numba kernels or numpy) and why."""
        if not jit_support.AVAILABLE:
            return ('numpy path (numba is not installed: pip install "numba>=0.60"; README, '
                    'Install)')
        if jit_support.switched_off():
            return f'numpy path ({jit_support.NO_JIT_ENV} is set)'
        job = self._compile
        if job is not None and job.error is not None:
            return (f'numpy path (compiling the numba kernels failed: '
                    f'{type(job.error).__name__}: {job.error})')
        if jit_support.compiling() and self._cache_filled:
            return ('numpy path while the numba kernels load from the cache in the background '
                    '(about a second; same results, slower)')
        if jit_support.compiling():
            return ('numpy path while the numba kernels compile in the background (numba\'s '
                    'cache is empty: about a minute on two cores; same results, slower)')
        return COMPILED

    def _warm_up(self) -> None:
        """Compile or load every cached kernel: the pipeline's and RVL's.

        RVL's too on raw input, so that numba's cache holds every kernel the node imports and
        the next start's cache check (jit.cache_filled) says "load", not "compile".
        """
        self._config.detector.warm_up()
        rvl.warm_up()

    def _on_compiled(self, job: jit_support.BackgroundCompile) -> None:
        # Runs on the compile thread; the node may already be shutting down.
        try:
            if job.error is not None:
                self.get_logger().error(f'now on the {self.compute_path()}')
            else:
                how = 'loaded from the cache' if self._cache_filled else 'compiled'
                self.get_logger().info(f'numba kernels {how} in {job.seconds:.1f} s; frames '
                                       'now take the compiled path')
            self._publish_status()
        except Exception:  # noqa: BLE001 - a node destroyed meanwhile has no logger or publisher
            pass

    def _publish_status(self) -> None:
        """Publish the latched ~/status line: 'ready: <which code processes the frames>'."""
        if self.context.ok():
            self._status_pub.publish(String(data=f'ready: {self.compute_path()}'))

    # -- the camera mount: parameters or TF ------------------------------------------------------
    def _make_mount_source(self, tf_buffer: Any) -> MountSource:
        """Return where the mount comes from; ValueError if use_tf is set and tf2 is missing."""
        target = str(self.get_parameter('cloud_frame_id').value)
        params = f'the parameters ({self._config.mount().describe()})'
        use_tf = bool(self.get_parameter('use_tf').value)
        if use_tf and tf_buffer is None:
            try:
                import tf2_ros
            except ImportError as error:
                # refused, not run on the parameters: Nav2 places the clearing cloud through
                # TF, so outputs placed otherwise would disagree with it unseen
                raise ValueError(
                    f'use_tf is true but tf2_ros cannot be imported ({error}): source the ROS 2 '
                    'setup (/opt/ros/jazzy/setup.bash) or install ros-jazzy-tf2-ros; or set '
                    'use_tf:=false to take the camera mount from the camera_* parameters, '
                    'which the URDF must then equal') from error
            tf_buffer = tf2_ros.Buffer()
            self._tf_listener = tf2_ros.TransformListener(tf_buffer, self)
        if not use_tf:
            self.get_logger().info(f'camera mount from {params}')
            return MountSource(None, target)
        static = bool(self.get_parameter('tf_static_mount').value)
        self.get_logger().info(f'camera mount from TF: {target} <- the depth image frame_id'
                               f'{" (static: looked up once)" if static else ""}; frames are '
                               'dropped while TF has no transform')
        return MountSource(tf_buffer, target, static=static, timeout=Duration(
            seconds=float(self.get_parameter('tf_timeout_s').value)))

    def _detector_for(self, msg: Any, config: NodeConfig) -> Any:
        """Return the frame's detector: the configured one, or one mounted where TF says.

        None (the frame dropped, said) when TF has no transform for the frame.
        """
        source = self._mount_source
        if source.buffer is None:
            return config.detector
        parameters = config.mount()
        mount = source.mount_for(msg.header.frame_id, RclpyTime.from_msg(msg.header.stamp),
                                 parameters)
        if mount is None:
            self._mount_said = source.source
            self._warn_skip('tf', f'{source.last_problem}; not published with the mount '
                                  'parameters (Nav2 places the clearing cloud through TF)')
            return None
        self._mount_said = f'{source.source}: {mount.describe()}'
        if mount != self._tf_mount:
            self.get_logger().info(f'camera mount from {self._mount_said}')
            self._mount_check.clear()   # a new mount: its own agreement with the floor
            self._tf_mount = mount
        if mount == parameters:
            return config.detector
        try:
            return config.detector_for(mount)
        except ValueError as error:
            self._warn_skip('mount', f'the mount from TF cannot be used: {error}')
            return None

    def _mount_cause(self) -> tuple[str, str]:
        """(where the mount comes from, how to correct it), for the mount check's warning."""
        if self._mount_source.buffer is not None:
            frame = self._image_frame or 'the depth image frame'
            return (f'the URDF (TF {self._mount_source.base_frame} <- {frame})',
                    "correct the camera joint's origin in the URDF")
        return ('the mount parameters (camera_height_m, camera_pitch_deg, camera_roll_deg)',
                'set them (its --params-out writes them)')

    # -- diagnostics ---------------------------------------------------------------------------
    def publish_diagnostics(self) -> None:
        """Publish the health of the period since the last report on /diagnostics (1 Hz)."""
        agreement = self._mount_check.agreement(*self._mount_cause())
        if agreement.warning:   # also in the log, for a robot without a diagnostics monitor
            self._throttled_logger('mount_check').warning(
                agreement.warning, throttle_duration_sec=MOUNT_WARN_THROTTLE_S)
        fallback = self._config.fallback_intrinsics
        context = DiagnosticsContext(
            uptime_s=time.monotonic() - self._started, depth_topic=self._depth_sub.topic_name,
            code_path=self.compute_path(),
            mount=self._mount_said or (
                f'parameters: {self._config.mount().describe()}'
                if self._mount_source.buffer is None else
                f'TF {self._mount_source.base_frame} <- the depth image frame: no frame yet'),
            camera_info_topic=self._info_sub.topic_name,
            fallback_intrinsics=(f'fx={fallback.fx:g} fy={fallback.fy:g} cx={fallback.cx:g} '
                                 f'cy={fallback.cy:g}'),
            mount_check=agreement.values(), mount_warning=agreement.warning)
        # hardware_id: one string for the node's life (diagnostic_updater's setHardwareID)
        status = health_status(self.stats.take(), context, name=self._diagnostics_name,
                               hardware_id=self._depth_sub.topic_name)
        if self.context.ok():
            msg = DiagnosticArray(status=[status])
            msg.header.stamp = self.get_clock().now().to_msg()
            self._diagnostics_pub.publish(msg)

    # -- parameters -------------------------------------------------------------------------
    def _parameter_values(self, changes: list[Parameter] | None = None) -> dict[str, Any]:
        values = {spec.name: self.get_parameter(spec.name).value for spec in ALL_PARAMS}
        for parameter in changes or ():
            values[parameter.name] = parameter.value
        return values

    @property
    def config(self) -> NodeConfig:
        """The configuration the next frame will use."""
        return self._config

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        # No side effect here: another callback may still refuse the set.
        undeclared = [p.name for p in parameters if not self.has_parameter(p.name)]
        if undeclared:   # rclpy lets an empty name through, and would create it
            return SetParametersResult(successful=False,
                                       reason=f'undeclared parameter(s): {undeclared}')
        try:
            build_config(self._parameter_values(parameters))
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _refuse_unknown_types(self, callback: Any, request: Any, response: Any) -> Any:
        """Refuse, with the reason, a set request holding a ParameterValue.type rclpy lacks."""
        bad = [(p.name, p.value.type) for p in request.parameters
               if p.value.type not in {t.value for t in Parameter.Type}]
        if not bad:
            return callback(request, response)
        reason = f'unknown ParameterValue.type for {bad}; nothing set'
        self.get_logger().warning(f'refused a parameter request: {reason}',
                                  throttle_duration_sec=WARN_THROTTLE_S)
        refused = SetParametersResult(successful=False, reason=reason)
        if hasattr(response, 'result'):
            response.result = refused
        else:
            response.results = [refused] * len(request.parameters)
        return response

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        config = build_config(self._parameter_values())  # validated just before
        # A new median K compiles its kernel (seconds for a K never used before) on a thread
        # of its own, not in this callback nor in a frame: frames take the numpy path
        # meanwhile. Nothing starts while a compilation already runs, or without numba.
        if not jit_support.compiling():
            job = jit_support.compile_in_background(config.detector.warm_up,
                                                    on_done=self._on_compiled)
            if job is not None:
                self._compile = job
                self._publish_status()
        self._config = config
        self._mount_check.clear()   # the mount parameters may have changed
        release_memory()   # a heavier configuration's last frame may be done already
        changed = ', '.join(f'{p.name}={p.value!r}' for p in parameters)
        self.get_logger().info(f'parameters updated, next frame uses: {changed}')

    # -- callbacks (executor thread): store only --------------------------------------------
    def _on_depth(self, msg: Image) -> None:
        self.stats.count('received')
        if self._mailbox.put(msg):
            self.stats.count('dropped')

    def _on_camera_info(self, msg: CameraInfo) -> None:
        camera = _CameraState.from_camera_info(msg)
        if camera.note is not None:
            self._throttled_logger('camera_info_note').info(
                f'CameraInfo on {self._info_sub.topic_name}: {camera.note}',
                throttle_duration_sec=WARN_THROTTLE_S)
        frame_gate.keep_camera(self._cameras, camera)

    def _on_odometry(self, msg: Odometry) -> None:
        pose = msg.pose.pose
        q = pose.orientation
        problem = self._poses.add(_stamp_ns(msg.header.stamp) * 1e-9, (
            pose.position.x, pose.position.y, yaw_from_quaternion(q.x, q.y, q.z, q.w)))
        if problem:
            self._throttled_logger('odometry').warning(
                f'odometry on {self._odom_sub.topic_name} refused: {problem}',
                throttle_duration_sec=WARN_THROTTLE_S)

    def _fuse(self, result: Any, msg: Any, config: NodeConfig) -> OccupancyGrid | None:
        """Fuse the frame's costmap; return the fused OccupancyGrid to publish (or None)."""
        if config.fusion is None:
            self._fused = None
            return None
        if self._fused is None or self._fused.params != config.fusion:
            self._fused = FusedGrid(config.fusion)
        stamp_s = _stamp_ns(msg.header.stamp) * 1e-9
        pose, why = self._poses.pose_at(stamp_s)
        if pose is None and not why:
            why = f'no odometry on {self._odom_sub.topic_name}'
        update = self._fused.update(result.costmap, pose, pose_stamp_s=stamp_s,
                                    no_pose_reason=why)
        # One call site per severity: rclpy refuses ("Logger severity cannot be changed
        # between calls") a call site whose severity changes, which skipped the frame.
        if update.message and update.warning:
            self.get_logger().warning(update.message)
        elif update.message:
            self.get_logger().info(update.message)
        return costmap_to_occupancy_grid(self._fused.to_costmap(), stamp=msg.header.stamp,
                                         frame_id=config.odom_frame)

    def _log_stats(self) -> None:
        period = self.stats.take(reader='log')
        mean_ms = period.sum_ms / period.processed if period.processed else 0.0
        self.get_logger().info(
            f'{period.processed} frames processed in {period.seconds:.1f} s '
            f'({period.processed / period.seconds:.1f} fps), mean {mean_ms:.1f} ms/frame; '
            f'{period.dropped} dropped (a newer frame came first), '
            f'{sum(period.skipped.values())} skipped (bad input), {period.errors} errors')

    # -- worker thread ------------------------------------------------------------------------
    def _work(self) -> None:
        config = self._config
        while (msg := self._mailbox.take()) is not None:
            if self._config is not config:   # the old parameters' last frame is done
                config = self._config
                release_memory()   # what a heavier configuration held goes back (budget.md)
            self.handle_frame(msg)

    def _throttled_logger(self, kind: str) -> Any:
        """Return the logger of one kind of problem, throttled on its own."""
        # rclpy throttles per logger object and call site: one logger per kind keeps an unknown
        # encoding from hiding a size mismatch.
        if kind not in self._warn_loggers:
            self._warn_loggers[kind] = rclpy.logging.get_logger(self.get_logger().name)
        return self._warn_loggers[kind]

    def _warn_skip(self, kind: str, text: str) -> None:
        """Warn about a skipped frame; each kind of problem is throttled on its own."""
        self.stats.skipped(kind.split(':', 1)[0])
        self._throttled_logger(kind).warning(f'skipping depth frame: {text}',
                                             throttle_duration_sec=WARN_THROTTLE_S)

    def _frame_intrinsics(self, msg: Any, shape: tuple[int, ...],
                          config: NodeConfig) -> tuple[Intrinsics | None, bool]:
        """Return the frame's intrinsics (None: skipped) and whether they are the fallback."""
        camera = frame_gate.camera_for(list(self._cameras), _stamp_ns(msg.header.stamp),
                                       config.camera_info_tolerance_ns)
        if isinstance(camera, frame_gate.Skip):
            self._warn_skip(camera.kind, camera.reason)
            return None, False
        verdict = frame_gate.choose_intrinsics(
            camera, shape, use_fallback=config.use_fallback_intrinsics,
            fallback=config.fallback_intrinsics,
            no_camera='' if camera is not None else (
                f'no CameraInfo received yet on {self._info_sub.topic_name} (set '
                'use_fallback_intrinsics to use fallback_fx/fy/cx/cy)'))
        if verdict.note is not None:
            self._throttled_logger('fallback').info(verdict.note,
                                                    throttle_duration_sec=WARN_THROTTLE_S)
        if verdict.skip is not None:
            self._warn_skip(verdict.skip.kind, verdict.skip.reason)
        return verdict.intrinsics, camera is None

    def handle_frame(self, msg: Image) -> bool:
        """Process one depth Image and publish its outputs; False if the frame was skipped."""
        start = time.perf_counter()
        config = self._config
        depth = frame_gate.decode(msg)
        if isinstance(depth, frame_gate.Skip):
            self._warn_skip(depth.kind, depth.reason)
            return False
        intrinsics, fallback = self._frame_intrinsics(msg, depth.shape, config)
        if intrinsics is None:
            return False
        skip = frame_gate.check_depth(depth, msg)
        if skip is not None:
            self._warn_skip(skip.kind, skip.reason)
            return False
        detector = self._detector_for(msg, config)
        if detector is None:
            return False
        try:
            result = detector.process(depth, intrinsics)
            marks, clearing_points = config.nav2_clouds(result)
            messages = result_to_messages(
                result, stamp=msg.header.stamp, cloud_frame_id=config.cloud_frame_id,
                costmap_frame_id=config.costmap_frame_id, image_frame_id=msg.header.frame_id,
                with_ground=config.publish_ground,
                overlay_rgb=(render_overlay(result.depth_m, result.labels)
                             if config.publish_overlay else None),
                clearing_points=clearing_points, marking_points=marks)
            fused = self._fuse(result, msg, config)
        except ValueError as error:
            self._warn_skip('pipeline', str(error))
            return False
        except Exception as error:  # noqa: BLE001 - the node must survive any frame
            self.stats.count('errors')
            self.get_logger().error(f'pipeline failed on a frame, skipping it: '
                                    f'{type(error).__name__}: {error}',
                                    throttle_duration_sec=WARN_THROTTLE_S)
            return False
        try:
            if fused is not None:
                messages['fused'] = fused
            for key, out in messages.items():
                self._pubs[key].publish(out)
            elapsed_ms = (time.perf_counter() - start) * 1e3
            self._time_pub.publish(Float64(data=elapsed_ms))
        except Exception as error:  # noqa: BLE001 - e.g. the context shut down meanwhile
            if self.context.ok():
                self.get_logger().error(f'publishing failed: {type(error).__name__}: {error}',
                                        throttle_duration_sec=WARN_THROTTLE_S)
            return False
        self.stats.processed(elapsed_ms, fallback=fallback)
        self._mount_check.add(result.floor)
        self._image_frame = msg.header.frame_id
        return True

    def close(self) -> None:
        """Stop the worker thread (call before ``destroy_node``)."""
        self._mailbox.close()
        if self._worker.is_alive() and self._worker is not threading.current_thread():
            self._worker.join(timeout=10.0)


def spin_forever(node: DetectorNode) -> None:
    """Spin until shutdown; an exception escaping a callback is logged, never fatal."""
    executor = EventsExecutor(context=node.context)
    executor.add_node(node)
    logger = rclpy.logging.get_logger(f'{node.get_logger().name}.executor')
    try:
        while node.context.ok():
            try:
                executor.spin_once(timeout_sec=0.5)
            except (KeyboardInterrupt, ExternalShutdownException):
                raise
            except Exception as error:  # noqa: BLE001 - the node must outlive any callback
                logger.error(f'a callback raised {type(error).__name__}: {error}; '
                             'the node goes on', throttle_duration_sec=WARN_THROTTLE_S)
    finally:
        executor.shutdown(timeout_sec=1.0)


def help_text() -> str:
    """Return ``detector --help``: usage, topics and every parameter with its range."""
    lines = [
        'usage: detector [-h] [--ros-args --params-file FILE [-p NAME:=VALUE] [-r FROM:=TO] ...]',
        '',
        'ROS 2 node "obstacle_detector": depth image -> obstacle cloud and ground-plane costmap.',
        '',
        'topics (relative names; remap with -r; their QoS: docs/node.md):',
        '  in   depth/image_raw           sensor_msgs/Image, 16UC1/mono16 [mm] or 32FC1 [m]',
        '  in   depth/image_raw/compressedDepth  CompressedImage (PNG or RVL), by depth_transport',
        '  in   depth/image_raw/compressed  CompressedImage (PNG or TIFF), by depth_transport',
        '  in   depth/camera_info         sensor_msgs/CameraInfo (P, or K when P is all zero)',
        '  in   odom                      nav_msgs/Odometry (odom_topic), if fuse',
        *(f'  out  {topic:<25} {kind.__name__}' + (f', if {switch}' if switch else '')
          for kind, topic, switch in OUTPUTS.values()),
        '  out  ~/processing_time_ms      std_msgs/Float64 per frame',
        '  out  ~/status                  std_msgs/String, latched: "ready: <which code runs>"',
        '  out  /diagnostics              diagnostic_msgs/DiagnosticArray, 1 Hz',
        '',
        f'parameters (section "{PARAMS_FILE_KEY}:" or "/**:" of a --params-file; name  type  '
        'default  range; use_sim_time is rclpy\'s own, diagnostic_updater.use_fqn (bool, false: '
        '/diagnostics names the status "obstacle_detector: ...", true: after the full name) '
        'diagnostic_updater\'s):',
    ]
    for spec in ALL_PARAMS:
        default = repr(spec.default) if isinstance(spec.default, str) else str(spec.default)
        head = [spec.name, spec.type_name, default, spec.range_text,
                'read-only' if spec.read_only else '']
        lines += ['  ' + '  '.join(filter(None, head)), f'      {spec.description}']
    lines += ['', 'example: detector --ros-args --params-file params/corridor.yaml '
              '-r depth/image_raw:=/kinect2/sd/image_depth_rect '
              '-r depth/camera_info:=/kinect2/sd/camera_info']
    return '\n'.join(lines)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run obstacle_detection detector``; returns the exit code."""
    argv = list(sys.argv if args is None else args)
    files = params_files_in_args(argv)
    try:
        for path in files:   # rcl would end in a raw RCLError traceback, or refuse an
            check_params_file(Path(path))   # integer for a float naming neither file nor fix
    except RosInputError as error:
        print(f'detector: error: {error}', file=sys.stderr)
        return 1
    try:
        own = rclpy.utilities.remove_ros_args(argv)[1:]
        if '-h' in own or '--help' in own:
            print(help_text())
            return 0
        if own:
            print(f'detector: error: unrecognized arguments: {" ".join(own)} (node options go '
                  'after --ros-args; see detector --help)', file=sys.stderr)
            return 2
        rclpy.init(args=argv)
    except Exception as error:  # noqa: BLE001 - rcl's own wording of a bad --ros-args
        print(f'detector: error: {type(error).__name__}: {error}', file=sys.stderr)
        return 2
    node = None
    try:
        try:
            node = DetectorNode()
        except (ValueError, ParameterException) as error:
            rclpy.logging.get_logger(NODE_NAME).fatal(f'invalid parameters: {error}')
            return 1
        for path in files:
            for problem in params_file_problems(path, node.get_fully_qualified_name()):
                node.get_logger().warning(problem)
        spin_forever(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass   # Ctrl-C at any point of the start-up or the run: a clean stop
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
