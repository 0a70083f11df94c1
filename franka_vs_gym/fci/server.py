"""FCIServer: libfranka's network interface (the FCI) in front of the simulated FER.

An unmodified libfranka client (pylibfranka, franky, libfranka C++ programs...) that drives the real robot at
``172.16.0.2`` drives the simulated one when given the server's address::

    with FCIServer(lockstep=True) as server:          # 127.0.0.1, robot TCP+UDP 1337, gripper TCP+UDP 1338
        subprocess.run([sys.executable, "my_robot_script.py", server.host])
        image = server.render_camera()                 # the simulated wrist camera, from this process

One thread serves the robot and the gripper: TCP commands (Connect, Move, StopMove, setters, GetRobotModel,
AutomaticErrorRecovery; gripper Homing/Move/Grasp/Stop), UDP robot states out and commands in. Modes:

- ``lockstep=True``: one 1 ms physics step per control command received, and one state in reply; while no motion
  is commanded, states keep flowing every millisecond of wall time with the physics frozen (the arm still, time
  standing), except while the hand moves. Deterministic and as fast as the client.
- ``lockstep=False`` (real time): the plant steps every millisecond of wall time; a command that misses its cycle
  lowers ``control_command_success_rate`` and more than :data:`~franka_vs_gym.fci.robot.MAX_MISSED_COMMANDS` in a
  row trigger ``communication_constraints_violation``.

Several servers run side by side on different loopback addresses (127.0.0.2, 127.0.0.3...).
"""

from __future__ import annotations

import errno
import inspect
import selectors
import socket
import struct
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.fci import codec
from franka_vs_gym.fci.codec import (
    Command,
    ConnectStatus,
    GripperCommand,
    GripperStatus,
    MoveRequest,
    MoveStatus,
    RecoveryStatus,
    RobotCommand,
    RobotMode,
    SetterStatus,
    StopMoveStatus,
)
from franka_vs_gym.fci.gripper import SimulatedHand
from franka_vs_gym.fci.robot import FCIRobot
from franka_vs_gym.fci.urdf import robot_urdf
from franka_vs_gym.model.description import RobotDescription, robot_description

_TICK = 0.001  # s of wall time between idle states (and the real-time control period)
# Lock-step, between a Move and its first command: frozen states keep the client from waiting forever, but every
# extra one the client drains changes the time step it sees, so they are rare.
_START_PHASE_PERIOD = 0.05
# s: a real-time cycle that starts later than this after its time re-anchors the 1 ms grid at its start (whole
# cycles it overran are counted as dropped; plant time falls behind wall time): the next cycle comes a full period
# after this one started, so each state the server sends leaves the client the period minus the server's own
# processing for its answer, as on the robot (the FCI's budget: round trip + client + robot processing < 1 ms), and
# an overloaded machine shows as a slower plant, not as missed commands. (Keeping the grid for lateness up to half
# a cycle left a Python client a median 0.24 ms, and ran cycles 0.4 ms apart: 57-62 % of its commands came late.)
_MAX_LATE = 0.0001
_HAND_STEPS_PER_TICK = 25  # lock-step physics steps per wall-time tick while only the hand moves
_CHUNK = 60000  # rows per block of a --record buffer (1 min at 1 kHz, 27 MB)


class _Conn:
    """One TCP connection with its receive buffer."""

    def __init__(self, sock: socket.socket, kind: str) -> None:
        self.sock, self.kind = sock, kind
        self.buf = bytearray()
        self.udp_addr: tuple[str, int] | None = None
        self.peer = sock.getpeername()[0]

    def send(self, data: bytes) -> None:
        try:
            self.sock.sendall(data)
        except OSError:
            pass


class FCIServer:
    """A libfranka-protocol server (robot protocol 10, gripper protocol 3) on a simulated FER.

    Parameters
    ----------
    host : loopback (or other local) address to bind, default "127.0.0.1".
    lockstep : one physics step per control command (deterministic) instead of 1 kHz of wall time.
    model : ModelConfig, path to a calibrated-model file, or None: the robot the plant and its internal model are
        built from (tool, payload, gravity vector, friction...).
    robot : RobotDescription or name ("fer", "fr3" when registered): limits and the URDF handed to ``load_model``.
    q0 : (7,) start joint position, rad (default the description's neutral pose).
    tags : AprilTags in the scene (``[TagSpec()]`` for the default 8 cm tag on the table).
    camera : add the wrist camera (see :meth:`render_camera`).
    table : put the table in the scene.
    extra_worldbody : raw MJCF added to the world (objects to grasp, obstacles).
    record : path of a workbench log (``.csv`` or ``.npz`` + ``.json`` sidecar) written at :meth:`stop` with one
        row per physics step while a robot client is connected (the values the client received).
    port, gripper_port : 1337 and 1338 as libfranka fixes them (change only for tests of the server itself).
    max_missed_commands : real time: cycles in a row without a command before the communication-constraints reflex
        (default :data:`~franka_vs_gym.fci.robot.MAX_MISSED_COMMANDS`, 20).
    truth : path of a truth file (:mod:`franka_vs_gym.fci.truth`: a calibrated model file or a list of effects with
        values) or a :class:`~franka_vs_gym.fci.truth.Truth`: the plant carries it, the robot's own model (``model``:
        what ``load_model``, ``set_load``, the internal controllers and the gravity compensation use) does not.
    verbose : print the ready line and connection events.
    table_height : a raised table in front of the robot with its top at this height (m, base frame) instead of the
        table under it (:func:`~franka_vs_gym.assets.mjcf.raised_table_xml`; 0.59 m is the bare flange's height at
        the neutral pose).
    tool : replace the model's tool: "none" (the bare flange: no hand, no gripper) or "franka_hand".
    rotor_inertia : the plant carries the robot's effective armature (``RobotDescription.rotor_inertia``, the motors
        as a torque controller feels them; default True, as the robot; see ``FrankaSim``).

    Attributes
    ----------
    sim : the :class:`~franka_vs_gym.sim.FrankaSim` behind the interface (hold :attr:`lock` while touching it).
    robot : the :class:`~franka_vs_gym.fci.robot.FCIRobot` (modes, controllers, reflexes).
    hand : the :class:`~franka_vs_gym.fci.gripper.SimulatedHand`.
    """

    def __init__(self, host: str = "127.0.0.1", *, lockstep: bool = False, model: Any = None,
                 robot: RobotDescription | str | None = None, q0: Any = None, tags: list | None = None,
                 camera: bool = True, table: bool = True, extra_worldbody: str = "",
                 record: str | Path | None = None,
                 port: int = codec.ROBOT_PORT,
                 gripper_port: int = codec.GRIPPER_PORT, max_missed_commands: int | None = None,
                 verbose: bool = True, truth: Any = None, rotor_inertia: bool = True,
                 table_height: float | None = None, tool: str | None = None) -> None:
        from franka_vs_gym.assets.mjcf import raised_table_xml
        from franka_vs_gym.sim import FrankaSim

        self.host, self.port, self.gripper_port = host, int(port), int(gripper_port)
        self.lockstep = bool(lockstep)
        self.description = robot_description(robot)
        if record is not None:
            record = Path(record)
            if record.suffix.lower() not in (".csv", ".npz"):
                raise ValueError(f"--record {record}: use a .csv or .npz file name")
            for p in (record, record.with_name(record.name + ".json")):
                if p.exists():
                    raise FileExistsError(f"{p} exists; choose a new log name (nothing is overwritten)")
        self.record_path = record
        if tool is not None:  # the model's tool replaced ("none": the bare flange, as libfranka's force example wants)
            from franka_vs_gym.model.config import Tool, resolve_config

            model = resolve_config(model, self.description).copy(tool=Tool.named(tool))
        if table_height is not None:  # a raised table in front of the robot instead of the one under it
            extra_worldbody = raised_table_xml(table_height) + extra_worldbody
            table = False
        self.table_height = table_height
        kwargs: dict[str, Any] = {"camera": camera, "tags": tags, "table": table, "extra_worldbody": extra_worldbody}
        if q0 is not None:
            kwargs["q0"] = q0
        if "rotor_inertia" in inspect.signature(FrankaSim).parameters:
            kwargs["rotor_inertia"] = bool(rotor_inertia)  # the robot's motors as a torque controller feels them
        if "robot" in inspect.signature(FrankaSim).parameters:
            kwargs["robot"] = self.description
        elif self.description.name != "fer":
            raise ValueError(f"robot {self.description.name!r}: this simulator builds the FER only")
        if "reflexes" in inspect.signature(FrankaSim).parameters:
            # FCIRobot enforces the FER's reflexes at the protocol level (motion-generator checks on the commands
            # first, as libfranka does, then its own plant checks); the simulator's would pre-empt them when the
            # internal controller overshoots a command at the limit
            kwargs["reflexes"] = False
        self.truth = None
        if truth is None:
            self.sim = FrankaSim(model, **kwargs)
            self.robot = FCIRobot(self.sim, self.description)
        else:
            self.sim, self.robot = self._hidden_truth(truth, model, kwargs)
        if max_missed_commands is not None:
            self.robot.max_missed_commands = int(max_missed_commands)
        self.hand = SimulatedHand(self.sim)
        self.urdf = robot_urdf(self.description)
        self.lock = threading.RLock()
        self.verbose = verbose
        self._thread: threading.Thread | None = None
        self._running = False
        self._ready = threading.Event()
        #: set by the serving thread as it ends. stop() waits on it, not on Thread.join / is_alive: on Python < 3.13
        #: a join interrupted by a signal's exception (Ctrl-C, SIGTERM in serve_forever) can leave the thread marked
        #: stopped while it still runs, and closing the sockets under it then failed its accept ("Bad file
        #: descriptor") after every SIGTERM that followed a client
        self._done = threading.Event()
        self._error: BaseException | None = None
        self.message_id = 0
        self.gripper_message_id = 0
        self.move_id: int | None = None
        self.move_conn: _Conn | None = None
        self.robot_conn: _Conn | None = None
        self.gripper_conns: list[_Conn] = []
        self.commanded = False  # lockstep: a motion's first command has arrived
        self._next_start_state = 0.0
        self.steps = 0
        self._rows: list[np.ndarray] = []  # full (_CHUNK, 57) blocks of the record, then the current one
        self._chunk = np.empty((_CHUNK, 57))
        self._n_in_chunk = 0
        self.deadlines_met = 0
        self.deadlines_total = 0
        self.late_cycles = 0  # real-time cycles the server itself could not run in time (dropped)
        self.late_cycles_moving = 0  # of which while a motion ran
        self.late_commands = 0  # real time: commands that arrived after their cycle (dropped, as the FCI drops them)
        self.motion_stats: list[dict[str, Any]] = []  # real time: one entry per finished motion (see _motion_ended)
        self._motion_start = (0, 0, 0, 0)  # (deadlines_total, deadlines_met, late_cycles_moving, late_commands) at
        # the motion's start
        self._last_applied_id = 0  # real time: message id answered by the last command applied
        self._owed_since: float | None = None  # real time: when the first state the client has not answered went out
        self._renderers: dict[tuple[int, int], Any] = {}

    def _hidden_truth(self, truth: Any, model: Any, kwargs: dict[str, Any]) -> tuple[Any, FCIRobot]:
        """The plant built from the truth, the robot's model from ``model``; the robot's gravity compensation is
        its own model's (MuJoCo's gravcomp compensates the plant's bodies: the difference is commanded)."""
        from franka_vs_gym.fci.truth import Truth, load_truth
        from franka_vs_gym.model.config import resolve_config
        from franka_vs_gym.model.franka_model import FrankaModel
        from franka_vs_gym.sim import FrankaSim

        believed = resolve_config(model, kwargs.get("robot", self.description))
        t = truth if isinstance(truth, Truth) else load_truth(truth, believed)
        kw = {k: v for k, v in kwargs.items() if k != "robot"}
        sim = FrankaSim(t.plant, undeclared_payload=t.payload, torque_noise=t.torque_noise, seed=t.seed,
                        joint_effects=t.joint_effects, **kw)
        sim.model = FrankaModel(believed)  # what the robot knows
        robot = FCIRobot(sim, self.description)
        robot.plant_gravity = FrankaModel(t.plant)  # what the plant's gravcomp bodies weigh
        self.truth = t
        return sim, robot

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> FCIServer:
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def start(self) -> None:
        """Bind the sockets and serve in a background thread; returns when the server is ready."""
        self._bind()
        self._running = True
        self._done.clear()
        self._thread = threading.Thread(target=self._serve, name=f"fci-{self.host}", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self.verbose:
            mode = "lock-step" if self.lockstep else "real-time"
            print(f"franka-vs serve: simulated {self.description.name.upper()} ready at {self.host} "
                  f"(robot TCP+UDP {self.port}, gripper {self.gripper_port}, {mode})", flush=True)

    def serve_forever(self) -> None:
        """Start and block until interrupted (Ctrl-C) or stopped (a Ctrl-C that arrives while starting, e.g. just
        after the ready line is printed, stops it the same way)."""
        try:
            self.start()
            while self._thread is not None and self._thread.is_alive():
                self._thread.join(0.2)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def stop(self) -> None:
        """Stop serving, close the sockets, write the recorded log (if any)."""
        self._running = False
        if self._thread is not None:
            self._done.wait(5.0)
            self._thread.join(0.5)
            self._thread = None
        for s in getattr(self, "_socks", []):
            try:
                s.close()
            except OSError:
                pass
        self._socks = []
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()
        if self.record_path is not None and (self._rows or self._n_in_chunk):
            self._write_log()
            self._rows, self._n_in_chunk = [], 0
        if self._error is not None:
            err, self._error = self._error, None
            raise RuntimeError(f"FCI server thread failed: {err}") from err

    def _bind(self) -> None:
        def tcp(port: int) -> socket.socket:
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((self.host, port))
            s.listen(4)
            s.setblocking(False)
            return s

        def udp(port: int) -> socket.socket:
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind((self.host, port))
            s.setblocking(False)
            return s

        socks = []
        try:
            for make, port in ((tcp, self.port), (udp, self.port), (tcp, self.gripper_port),
                               (udp, self.gripper_port)):
                socks.append(make(port))
        except OSError as e:
            for s in socks:
                s.close()
            if e.errno == errno.EADDRINUSE:
                raise OSError(e.errno, f"{self.host}:{port} is in use: another server or robot program runs "
                                       f"there; use another loopback address (--host 127.0.0.2)") from None
            if e.errno == errno.EADDRNOTAVAIL:
                raise OSError(e.errno, f"cannot bind {self.host}: not an address of this machine") from None
            raise
        self.tcp, self.udp, self.gtcp, self.gudp = socks
        self._socks = socks

    # ------------------------------------------------------------------ main loop
    def _serve(self) -> None:
        # select(2) waits to the microsecond; epoll and poll (DefaultSelector) round a timeout up to whole
        # milliseconds, which overslept every real-time cycle by up to 1 ms (periods of 1.4 ms, median)
        sel = selectors.SelectSelector()
        sel.register(self.tcp, selectors.EVENT_READ, "accept-robot")
        sel.register(self.gtcp, selectors.EVENT_READ, "accept-gripper")
        sel.register(self.udp, selectors.EVENT_READ, "udp")
        sel.register(self.gudp, selectors.EVENT_READ, "gudp")
        self._sel = sel
        self._ready.set()
        next_tick = time.perf_counter()
        pending: deque[RobotCommand] = deque()  # real time: commands received since the last cycle
        try:
            while self._running:
                now = time.perf_counter()
                timeout = max(0.0, next_tick - now)
                for key, _ in sel.select(timeout):
                    tag = key.data
                    if tag == "udp":
                        cmd = self._recv_command()
                        while cmd is not None:
                            if self.lockstep:
                                self._lockstep_command(cmd)
                            else:
                                pending.append(cmd)
                                self._owed_since = None  # the client is answering
                            cmd = self._recv_command()
                    elif tag == "gudp":
                        try:
                            while True:
                                self.gudp.recvfrom(64)
                        except BlockingIOError:
                            pass
                    elif tag in ("accept-robot", "accept-gripper"):
                        self._accept(key.fileobj, "robot" if tag == "accept-robot" else "gripper")
                    else:
                        self._read_tcp(tag)
                now = time.perf_counter()
                if now >= next_tick:
                    late = now - next_tick
                    next_tick += _TICK
                    if late > _MAX_LATE:  # the server itself started late (machine loaded): the grid restarts here,
                        lost = int(late / _TICK)  # overrun cycles are dropped, not replayed back to back (that would
                        self.late_cycles += lost  # count as client misses): the plant's time falls behind wall time,
                        if self.robot.moving:  # the client is not blamed
                            self.late_cycles_moving += lost
                        next_tick = now + _TICK
                    if self.lockstep:
                        self._lockstep_tick()
                    else:
                        self._realtime_tick(self._next_command(pending))
        except BaseException as e:  # reported by stop()
            self._error = e
        finally:
            try:
                for c in [self.robot_conn, *self.gripper_conns]:
                    if c is not None:
                        c.sock.close()
                sel.close()
            finally:
                self._done.set()

    def _recv_command(self) -> RobotCommand | None:
        try:
            data, _ = self.udp.recvfrom(2048)
        except (BlockingIOError, OSError):
            return None
        if len(data) != codec.ROBOT_COMMAND.size:
            return None
        return RobotCommand.decode(data)

    # ------------------------------------------------------------------ stepping
    def _physics_step(self, cmd: RobotCommand | None) -> tuple[str, ...]:
        with self.lock:
            reasons = self.robot.step(cmd)
            self.steps += 1
            done = self.hand.step(self.sim.dt)
            if done is not None:
                self._gripper_reply(*done)
        return reasons

    def _lockstep_command(self, cmd: RobotCommand) -> None:
        r = self.robot
        if not r.moving or cmd.message_id > self.message_id:
            return
        if self.commanded and cmd.message_id != self.message_id:
            return  # a late command for an older state
        self.commanded = True
        reasons = self._physics_step(cmd)
        self._after_step(cmd, reasons)

    def _after_step(self, cmd: RobotCommand | None, reasons: tuple[str, ...]) -> None:
        r = self.robot
        st = r.fill_state()
        if not reasons and r.moving:
            reasons = r.collision_reflex()
        if reasons:
            self._answer_move(MoveStatus.REFLEX_ABORTED)
            st = r.fill_state()
        elif cmd is not None and r.moving and (
                cmd.motion_generation_finished if r.finished_by == "motion" else cmd.torque_command_finished):
            r.finish_motion()
            self._answer_move(MoveStatus.SUCCESS)
            st = r.fill_state()
        self._record()
        self._send_state(st)

    def _lockstep_tick(self) -> None:
        r = self.robot
        if r.moving and self.commanded:
            self._send_gripper_state()
            return  # states go out one per command
        if r.moving and not self.hand.busy:  # waiting for the motion's first command
            now = time.perf_counter()
            if now < self._next_start_state:
                self._send_gripper_state()
                return
            self._next_start_state = now + _START_PHASE_PERIOD
        if self.hand.busy:  # the hand needs simulated time although no arm command advances it: lock-step runs
            reasons: tuple[str, ...] = ()  # it as fast as it can (several steps per tick, one state out)
            for _ in range(_HAND_STEPS_PER_TICK):
                reasons = self._physics_step(None)
                if reasons or not self.hand.busy:
                    break
                self._record()
            self._after_step(None, reasons)
        elif self.robot_conn is not None:  # (nobody to send to: the frozen plant needs no work)
            self._send_state(r.fill_state())
        self._send_gripper_state()

    def _next_command(self, pending: deque[RobotCommand]) -> RobotCommand | None:
        """Real time: this cycle's command, the one answering the newest state sent. A command answering an older
        state missed its cycle and is dropped, as the FCI drops a packet that violates the 1 ms constraint (FCI
        documentation, "Minimum system and network requirements": the cycle is extrapolated with constant
        acceleration, or the last torque reused; 20 dropped in a row stop the robot). Applying it one or more
        cycles late instead would time-shift the desired motion against the states the client has already been
        sent: a client that low-passes its next command against the state's ``q_d`` / ``O_T_EE_c`` / ``elbow_c``
        (libfranka's ``franka::Robot::control`` does, at 100 Hz by default) then filters against a value a cycle
        old, which steps the commanded velocity (franky's joint waypoint and elbow motions tripped
        ``*_velocity_discontinuity`` that way). The command after a skipped state (the client read the newer one;
        its ``period`` is 2 ms) answers the newest state and is taken, at the client's time
        (FCIRobot._to_command_time)."""
        cmd = None
        while pending:
            c = pending.popleft()
            if c.message_id == self.message_id or not self.robot.moving:
                cmd = c
            elif self.robot.moving and c.message_id > self._last_applied_id:
                self.late_commands += 1
        if cmd is not None:
            self._last_applied_id = cmd.message_id
        return cmd

    def _realtime_tick(self, cmd: RobotCommand | None) -> None:
        r = self.robot
        if r.moving:
            got = cmd is not None and cmd.message_id == self.message_id
            self.deadlines_total += 1
            self.deadlines_met += got
            silent = None
            if cmd is None and self._owed_since is not None:  # cycles of wall time the client has owed an answer
                silent = int((time.perf_counter() - self._owed_since) / _TICK)
            r.count_command(got, silent)
            if not r.moving:  # communication reflex
                self._answer_move(MoveStatus.REFLEX_ABORTED)
        reasons = self._physics_step(cmd if r.moving else None)
        self._after_step(cmd, reasons)
        self._send_gripper_state()

    def _send_state(self, st) -> None:
        self.message_id += 1
        if self._owed_since is None and not self.lockstep and self.robot.moving:
            self._owed_since = time.perf_counter()  # from now on the client owes a command
        conn = self.robot_conn
        if conn is not None and conn.udp_addr is not None:
            try:
                self.udp.sendto(st.encode(self.message_id), conn.udp_addr)
            except OSError:
                pass

    def _send_gripper_state(self) -> None:
        if not self.gripper_conns:
            return
        self.gripper_message_id = (self.gripper_message_id + 1) & 0xFFFFFFFF
        h = self.hand
        data = codec.GRIPPER_STATE.pack(self.gripper_message_id, h.width, h.max_width, h.is_grasped, 25)
        for c in self.gripper_conns:
            if c.udp_addr is not None:
                try:
                    self.gudp.sendto(data, c.udp_addr)
                except OSError:
                    pass

    def _record(self) -> None:
        """One row per physics step while a robot client is connected: what the client received (float32 on the
        wire), the simulated time."""
        if self.record_path is None or self.robot_conn is None:
            return
        f = self.robot.state.f
        row = self._chunk[self._n_in_chunk]
        row[0] = self.sim.get_time()
        for k, name in enumerate(("q", "dq", "tau_J", "tau_J_d", "q_d", "dq_d", "ddq_d", "tau_ext_hat_filtered")):
            row[1 + 7 * k:8 + 7 * k] = f[name]
        self._n_in_chunk += 1
        if self._n_in_chunk == _CHUNK:
            self._rows.append(self._chunk)
            self._chunk, self._n_in_chunk = np.empty((_CHUNK, 57)), 0

    def _write_log(self) -> None:
        from franka_vs_gym.validation.logs import MeasurementLog, save_log

        a = np.concatenate([*self._rows, self._chunk[:self._n_in_chunk]])
        cols = [a[:, 1 + 7 * k:8 + 7 * k] for k in range(8)]
        cfg = self.sim.model.config
        tool = cfg.tool.to_dict() if cfg.tool.name != "franka_hand" else "franka_hand"
        if cfg.tool.name == "none":
            tool = None
        log = MeasurementLog(a[:, 0], cols[0], cols[1], cols[2], tau_J_d=cols[3], q_d=cols[4], dq_d=cols[5],
                             ddq_d=cols[6], tau_ext_hat_filtered=cols[7], tool=tool, gravity=cfg.gravity,
                             controller={"law": "fci_session", "lockstep": self.lockstep,
                                         "rotor_inertia_kgm2": self.sim.rotor_inertia.tolist()},
                             extra={"source": "franka-vs serve", "robot": self.description.name})
        save_log(log, self.record_path)
        if self.verbose:
            print(f"franka-vs serve: recorded {len(a)} steps to {self.record_path} (+ .json sidecar)", flush=True)

    # ------------------------------------------------------------------ TCP
    def _accept(self, lsock: socket.socket, kind: str) -> None:
        try:
            sock, _ = lsock.accept()
        except BlockingIOError:
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn = _Conn(sock, kind)
        self._sel.register(sock, selectors.EVENT_READ, conn)

    def _close(self, conn: _Conn) -> None:
        try:
            self._sel.unregister(conn.sock)
        except (KeyError, ValueError):
            pass
        conn.sock.close()
        if conn is self.robot_conn:
            self.robot_conn = None
            if self.robot.moving:
                with self.lock:
                    self.robot.finish_motion()
            self.move_id, self.move_conn, self.commanded = None, None, False
        if conn in self.gripper_conns:
            self.gripper_conns.remove(conn)
            if not self.gripper_conns:
                self.hand.stop()

    def _read_tcp(self, conn: _Conn) -> None:
        try:
            data = conn.sock.recv(65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._close(conn)
            return
        conn.buf += data
        header = codec.ROBOT_HEADER if conn.kind == "robot" else codec.GRIPPER_HEADER
        while len(conn.buf) >= header.size:
            command, command_id, size = header.unpack_from(conn.buf)
            if size < header.size or size > 1 << 20:
                self._close(conn)  # not libfranka talking
                return
            if len(conn.buf) < size:
                break
            payload = bytes(conn.buf[header.size:size])
            del conn.buf[:size]
            if conn.kind == "robot":
                self._robot_command(conn, command, command_id, payload)
            else:
                self._gripper_command(conn, command, command_id, payload)
            if conn.sock.fileno() < 0:
                return

    def _answer_move(self, status: MoveStatus) -> None:
        if self.move_id is not None and self.move_conn is not None:
            self.move_conn.send(codec.status_response(Command.MOVE, self.move_id, status))
            if not self.lockstep:
                self._motion_ended(status)
        self.move_id, self.move_conn, self.commanded = None, None, False

    def _motion_started(self) -> None:
        self._last_applied_id = 0
        self._owed_since = None
        self._motion_start = (self.deadlines_total, self.deadlines_met, self.late_cycles_moving, self.late_commands)

    def _motion_ended(self, status: MoveStatus) -> None:
        """Real time: the finished motion's communication statistics, as the robot keeps them for
        ``control_command_success_rate`` and ``communication_constraints_violation``: cycles run, commands that
        answered their own cycle's state, commands that came after their cycle (dropped), the longest run of
        cycles without a command in time, and the cycles the server itself dropped because the machine ran it
        late (its plant time lags wall time by as many milliseconds; the robot, a real-time system, never drops
        one). Printed with ``verbose``, kept in :attr:`motion_stats`."""
        total0, met0, dropped0, late0 = self._motion_start
        cycles, in_time = self.deadlines_total - total0, self.deadlines_met - met0
        st = {"status": MoveStatus(status).name.lower(), "cycles": cycles, "in_time": in_time,
              "success_rate": in_time / cycles if cycles else 1.0, "max_missed_in_row": self.robot.worst_missed,
              "server_dropped": self.late_cycles_moving - dropped0, "late_commands": self.late_commands - late0}
        self.motion_stats.append(st)
        if self.verbose:
            print(f"franka-vs serve: motion {st['status']}: {cycles} cycles, {in_time} commands in their cycle "
                  f"({100 * st['success_rate']:.1f} %), {st['late_commands']} late (dropped), at most "
                  f"{st['max_missed_in_row']} cycles in a row without a command in time (reflex above "
                  f"{self.robot.max_missed_commands}), {st['server_dropped']} cycles dropped "
                  f"by the server (machine too slow)", flush=True)

    def _robot_command(self, conn: _Conn, command: int, cid: int, payload: bytes) -> None:
        r = self.robot
        if command == Command.CONNECT:
            version, udp_port = codec.CONNECT_REQUEST.unpack_from(payload)
            if version != codec.ROBOT_VERSION:
                conn.send(codec.connect_response(cid, ConnectStatus.INCOMPATIBLE_LIBRARY_VERSION))
                return
            if self.robot_conn is not None and self.robot_conn is not conn:
                self._close(self.robot_conn)  # the robot serves one client at a time: the newest wins
            conn.udp_addr = (conn.peer, udp_port)
            self.robot_conn = conn
            conn.send(codec.connect_response(cid, ConnectStatus.SUCCESS))
            with self.lock:
                self._send_state(r.fill_state())
            if self.verbose:
                print(f"franka-vs serve: robot client connected from {conn.peer}", flush=True)
            return
        if conn is not self.robot_conn:
            return  # commands before Connect
        try:
            cmd = Command(command)
        except ValueError:
            conn.send(codec.status_response(command, cid, SetterStatus.COMMAND_NOT_POSSIBLE_REJECTED))
            return
        with self.lock:
            if cmd == Command.GET_ROBOT_MODEL:
                conn.send(codec.robot_model_response(cid, self.urdf))
            elif cmd == Command.MOVE:
                req = MoveRequest.decode(payload)
                if r.robot_mode != RobotMode.IDLE or self.move_id is not None:
                    conn.send(codec.status_response(cmd, cid, MoveStatus.COMMAND_NOT_POSSIBLE_REJECTED))
                    return
                r.start_motion(req.controller_mode, req.motion_generator_mode)
                self.move_id, self.move_conn, self.commanded = cid, conn, False
                self._motion_started()
                self._send_state(r.fill_state())  # the new modes are on the wire before "motion started"
                conn.send(codec.status_response(cmd, cid, MoveStatus.MOTION_STARTED))
                self._send_state(r.state)  # for a client that took "motion started" first
                self._next_start_state = time.perf_counter() + _START_PHASE_PERIOD
            elif cmd == Command.STOP_MOVE:
                if r.moving:
                    r.finish_motion()
                    self._answer_move(MoveStatus.PREEMPTED)
                conn.send(codec.status_response(cmd, cid, StopMoveStatus.SUCCESS))
                self._send_state(r.fill_state())
            elif cmd == Command.AUTOMATIC_ERROR_RECOVERY:
                if r.moving:
                    conn.send(codec.status_response(cmd, cid, RecoveryStatus.COMMAND_NOT_POSSIBLE_REJECTED))
                    return
                r.automatic_error_recovery()
                self._send_state(r.fill_state())  # in the client's queue before the reply: it reads the recovery
                conn.send(codec.status_response(cmd, cid, RecoveryStatus.SUCCESS))
            else:
                status = self._setter(cmd, payload)
                if not r.moving:
                    self._send_state(r.fill_state())  # ... and the new setting
                conn.send(codec.status_response(cmd, cid, status))

    def _setter(self, cmd: Command, payload: bytes) -> SetterStatus:
        r = self.robot
        if r.moving:
            return SetterStatus.COMMAND_NOT_POSSIBLE_REJECTED
        fmt = codec.REQUEST_STRUCTS[cmd]
        try:
            values = np.array(fmt.unpack_from(payload), dtype=float) if fmt is not None else np.zeros(0)
        except struct.error:
            return SetterStatus.INVALID_ARGUMENT_REJECTED
        if not np.isfinite(values).all():
            return SetterStatus.INVALID_ARGUMENT_REJECTED
        if cmd == Command.SET_JOINT_IMPEDANCE:
            if (values < 0).any():
                return SetterStatus.INVALID_ARGUMENT_REJECTED
            r.set_joint_impedance(values)
        elif cmd == Command.SET_CARTESIAN_IMPEDANCE:
            if (values < 0).any():
                return SetterStatus.INVALID_ARGUMENT_REJECTED
            r.set_cartesian_impedance(values)
        elif cmd == Command.SET_COLLISION_BEHAVIOR:
            v = np.split(values, np.cumsum([7, 7, 7, 7, 6, 6, 6, 6])[:-1])
            # nominal thresholds (the acceleration-phase ones are not distinguished here)
            r.set_collision_behavior(v[2], v[3], v[6], v[7])
        elif cmd in (Command.SET_EE_TO_K, Command.SET_NE_TO_EE):
            T = values.reshape(4, 4, order="F")
            R = T[:3, :3]
            if not (np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.allclose(T[3], (0, 0, 0, 1))):
                return SetterStatus.INVALID_ARGUMENT_REJECTED
            if cmd == Command.SET_EE_TO_K:
                r.set_EE_to_K(T)
            else:
                r.set_NE_to_EE(T)
        elif cmd == Command.SET_LOAD:
            m, com, inertia = values[0], values[1:4], values[4:13].reshape(3, 3, order="F")
            if m < 0 or not np.allclose(inertia, inertia.T, atol=1e-9):
                return SetterStatus.INVALID_ARGUMENT_REJECTED
            r.set_load(m, com, inertia)
        # SET_GUIDING_MODE: accepted; hand guiding is not simulated
        return SetterStatus.SUCCESS

    # ------------------------------------------------------------------ gripper
    def _gripper_reply(self, command: int, cid: int, status: GripperStatus) -> None:
        for c in self.gripper_conns:
            c.send(codec.gripper_message(command, cid, codec.GRIPPER_STATUS_RESPONSE.pack(status)))

    def _gripper_command(self, conn: _Conn, command: int, cid: int, payload: bytes) -> None:
        if command == GripperCommand.CONNECT:
            version, udp_port = codec.GRIPPER_CONNECT_REQUEST.unpack_from(payload)
            ok = version == codec.GRIPPER_VERSION
            status = ConnectStatus.SUCCESS if ok else ConnectStatus.INCOMPATIBLE_LIBRARY_VERSION
            conn.send(codec.gripper_message(command, cid, codec.GRIPPER_CONNECT_RESPONSE.pack(
                status, codec.GRIPPER_VERSION)))
            if ok:
                conn.udp_addr = (conn.peer, udp_port)
                self.gripper_conns.append(conn)
                self._send_gripper_state()
            return
        if conn not in self.gripper_conns:
            return
        with self.lock:
            if command == GripperCommand.STOP:
                ended = self.hand.stop()
                if ended is not None:
                    self._gripper_reply(ended[0], ended[1], GripperStatus.ABORTED)
                conn.send(codec.gripper_message(command, cid, codec.GRIPPER_STATUS_RESPONSE.pack(
                    GripperStatus.SUCCESS)))
                return
            if self.hand.busy:  # a new command preempts the running one
                ended = self.hand.stop()
                if ended is not None:
                    self._gripper_reply(ended[0], ended[1], GripperStatus.ABORTED)
            if command == GripperCommand.HOMING:
                status = self.hand.start(command, cid)
            elif command == GripperCommand.MOVE:
                width, speed = codec.GRIPPER_MOVE_REQUEST.unpack_from(payload)
                status = self.hand.start(command, cid, width, speed)
            elif command == GripperCommand.GRASP:
                width, ei, eo, speed, force = codec.GRIPPER_GRASP_REQUEST.unpack_from(payload)
                status = self.hand.start(command, cid, width, speed, force, ei, eo)
            else:
                status = GripperStatus.FAIL
            if status is not None:
                conn.send(codec.gripper_message(command, cid, codec.GRIPPER_STATUS_RESPONSE.pack(status)))

    # ------------------------------------------------------------------ camera
    def render_camera(self, width: int = 320, height: int = 240) -> np.ndarray:
        """An RGB image (height, width, 3) uint8 of the simulated wrist camera, rendered in the calling thread."""
        import mujoco

        key = (width, height)
        r = self._renderers.get(key)
        if r is None:
            r = self._renderers[key] = mujoco.Renderer(self.sim.world.model, height, width)
        with self.lock:
            r.update_scene(self.sim.world.data, camera=self.sim.camera_name())
        return r.render()

    def state(self) -> dict[str, Any]:
        """The current robot state as a dict of libfranka field names (decoded from what the client receives)."""
        with self.lock:
            return codec.decode_robot_state(self.robot.fill_state().encode(self.message_id))

    def __repr__(self) -> str:
        return (f"FCIServer(host={self.host!r}, lockstep={self.lockstep}, robot={self.description.name!r}, "
                f"steps={self.steps})")


__all__ = ["FCIServer"]
