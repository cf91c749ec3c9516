"""The simulator core: one world, one fixed step order.

``World.step`` always runs, in this order:

1. validate actions (ego control, RSU message);
2. the active RSU's message enters the V2X channel (serialized and counted there);
3. ego dynamics (kinematic bicycle) under the agent's control, perturbed when a scenario set
   ``control_noise`` on the previous tick (ControlLoss; the applied control is ``applied_control``);
4. traffic lights, NPC vehicles and bicycles (IDM), pedestrians, then each scenario's hook;
5. respawn NPCs that left the map or are stuck;
6. collisions (an exact box test; a pymunk query on the reference path) and infraction / route-progress events;
7. ``tick += 1``; perception: which actors the ego and the active RSU(s) see (2.5D occlusion);
8. the channel delivers what is due into the ego's inbox.

The adapters (PettingZoo, Gymnasium, TorchRL) only turn this state into observations.
"""

from __future__ import annotations

import numpy as np

from ..core.actors import (
    EGO,
    EGO_HEIGHT,
    EGO_LENGTH,
    EGO_WIDTH,
    ActorTable,
)
from ..core.classes import (
    CAR,
    EMERGENCY_VEHICLE,
    STATIC_OBSTACLE,
    TRAFFIC_LIGHT,
    TRAFFIC_SIGN,
)
from ..core.dynamics import VehicleParams, bicycle_step, bicycle_step_scalar
from ..core.geometry import row_norms
from ..core.jit import HAVE_JIT
from ..core.jit_args import PackedArgs
from ..core.jit_raycast import half_diagonals_kernel
from ..core.raycast import Boxes
from ..evaluation.infractions import EventMonitor
from ..evaluation.physics import CollisionWorld
from ..perception.jit_perception import (
    perceive_all_kernel,
    perceive_outputs,
    perceive_workspace,
    seen_rows_kernel,
)
from ..perception.objects import object_rows
from ..perception.visibility import VISIBILITY_SAMPLING, VISIBLE_THRESHOLD, visible_fraction
from ..town import get_town
from ..town.model import DRIVING, RAMP
from ..town.routes import Route, random_route
from ..traffic.pedestrians import SidewalkNetwork, ego_is_vehicle, step_walkers, walkers_args
from ..traffic.signals import SignalPlan
from ..traffic.spawn import populate
from ..traffic.vehicles import (
    flat_plans,
    followers_args,
    respawn_followers,
    step_followers,
    warn_spawn_shortfall,
)
from ..v2x.channel import Channel, ChannelConfig, empty_message
from ..v2x.jit_wire import builtin_message_kernel
from ..v2x.rsu import FACING_MAX_ANGLE, LOOKAHEAD_M, VIEW_HALF_ANGLE, RSUSet, deploy, select_active
from ..v2x.wire import FORMAT_OBJECTS, check_header, max_objects, pack_objects, pack_rows
from .config import EnvConfig
from .jit_batch import PerceiveBatch, TrafficBatch
from .jit_tick import traffic_tick_kernel

_NO_PAYLOAD = np.zeros(0, np.float32)
_NO_BYTES = np.zeros(0, np.uint8)
EGO_SENSOR_Z = 1.8  # m, ego camera height (occlusion is judged from here)
RSU_HFOV = np.deg2rad(120.0)  # rad, RSU LiDAR horizontal field of view


class StepError(RuntimeError):
    """Raised when stepping a world that has ended or was never reset."""


class World:
    """A V2XIntersection world: town, route, actors, RSUs, channel and event monitor."""

    def __init__(self, config: EnvConfig) -> None:
        self.config = config
        self.params = VehicleParams()
        pr = self.params
        self._max_rows = max_objects(config.max_payload_floats)  # object rows that fit a message
        self._bicycle_params = (pr.max_accel, pr.max_brake, pr.drag, pr.max_speed, pr.max_steer, pr.wheelbase,
                                config.dt)
        self.channel_config = ChannelConfig(
            latency_ticks=config.latency_ticks, loss_prob=config.loss_prob,
            bandwidth_bytes_per_s=config.bandwidth_bytes_per_s,
            max_payload_floats=config.max_payload_floats, encoding=config.encoding, dt=config.dt,
        )
        self.town = None
        self._traffic_one: TrafficBatch | None = None  # move_traffic's one-world batch (jit_batch), numba only
        self._perceive_one: PerceiveBatch | None = None  # perceive's (jit_batch)
        self._obs_args = PackedArgs()  # the objects observation's kernel arguments (numba)
        self._load_town(config.town)
        self.ended = True
        self.tick = 0
        self.spec = None  # the RouteSpec of the current episode when it comes from a suite

    def __getstate__(self) -> dict:
        """For copy and pickle: without the kernels' cached arguments (numba's typed lists cannot be
        pickled, and the generator-state views must be those of the copy); rebuilt on use."""
        state = self.__dict__.copy()
        state["_traffic_one"] = state["_perceive_one"] = None
        state["_traffic_args"] = state["_perceive_args"] = None
        return state

    def _load_town(self, name: str) -> None:
        """Switch to town ``name`` (towns and their derived tables are cached)."""
        if self.town is not None and self.town.name == name:
            return
        self.town = get_town(name)
        self.signals = SignalPlan(self.town)
        # the town's derived tables, shared by every world in it (one copy in the CPU's caches when a
        # batch steps many worlds of one town); nothing writes to them
        store = self.town.cache("world")
        if "tables" not in store:
            statics, heights, kinds = self._static_boxes()
            store["tables"] = (SidewalkNetwork(self.town), statics, heights, kinds,
                               (np.cos(statics[:, 4]), np.sin(statics[:, 4])), _half_diagonals(statics),
                               np.array([ln.id for ln in self.town.lanes if ln.kind in (DRIVING, RAMP)
                                         and ln.length > 15.0]))
        (self.sidewalks, self.static_boxes, self.static_heights, self.static_kinds, self.static_trig,
         self._static_half_diag, self._drive_lanes) = store["tables"]
        # static_boxes: (S, 5) x, y, length, width, yaw; static_trig: their yaw's cos, sin, and
        # _static_half_diag their half diagonals (for the kernels)
        self._perceive_args: tuple | None = None  # (table, rsus, kernel arguments)

    # ------------------------------------------------------------------ setup
    def _static_boxes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = self.town
        rows, heights, kinds = [t.buildings], [t.building_heights], [np.full(len(t.buildings), STATIC_OBSTACLE)]
        for poles, kind, h in ((t.lights, TRAFFIC_LIGHT, 5.0), (t.stop_signs, TRAFFIC_SIGN, 2.2)):
            if len(poles):
                rows.append(np.stack([poles[:, 0], poles[:, 1], np.full(len(poles), 0.4),
                                      np.full(len(poles), 0.4), poles[:, 2]], -1))
                heights.append(np.full(len(poles), h))
                kinds.append(np.full(len(poles), kind))
        return np.concatenate(rows, 0), np.concatenate(heights), np.concatenate(kinds).astype(np.int64)

    def reset(self, seed: int | None = None, route: Route | None = None, scenarios: list | None = None,
              spec=None) -> None:
        """Start an episode and populate the world from ``seed``.

        The episode comes from, in this order: ``spec`` (a route file's
        :class:`~.route_files.RouteSpec`, in its own town), ``route``/``scenarios`` given directly,
        ``config.suite`` (route ``config.route_index``, or one drawn from ``seed``),
        ``config.scenario`` (a route through a random site of that type), else a random route of
        ``config.route_length``.

        Args:
            seed: seeds the world's one random generator.
            route: the ego's route.
            scenarios: :class:`~.scenarios.base.Scenario` instances placed on ``route``; each gets
                ``max_actors`` reserved rows of the actor table and runs its hooks every tick.
            spec: a route file to replay.
        """
        cfg = self.config
        self.rng = np.random.default_rng(seed)
        if spec is None and route is None and cfg.suite is not None:
            from ..suites.route_files import load_suite_cached

            routes = load_suite_cached(cfg.suite)
            k = cfg.route_index if cfg.route_index is not None else int(self.rng.integers(len(routes)))
            if not 0 <= k < len(routes):
                raise ValueError(f"config: route_index={k} out of range for suite {cfg.suite!r} ({len(routes)} routes)")
            spec = routes[k]
        if spec is not None:
            from ..suites.route_files import build_episode_from_spec

            self._load_town(spec.town)
            route, scenarios = build_episode_from_spec(spec)
        elif route is None:
            self._load_town(cfg.town)
            if cfg.scenario is not None:
                from ..scenarios import build_episode

                route, scenarios = build_episode(cfg.scenario, self.town, self.rng)
            else:
                route = random_route(self.town, self.rng, cfg.route_length)
        self.spec = spec
        self.route = route
        self.scenarios = list(scenarios or [])
        self.plans: list[list[int]] = []
        n_base = 1 + cfg.num_vehicles + cfg.num_parked + cfg.num_pedestrians + cfg.num_bicycles
        n = n_base + sum(sc.max_actors for sc in self.scenarios)
        t = ActorTable.empty(n)
        t.kind[0], t.behaviour[0], t.active[0] = CAR, EGO, True
        t.length[0], t.width[0], t.height[0] = EGO_LENGTH, EGO_WIDTH, EGO_HEIGHT
        t.pos[0], t.yaw[0] = self.route.points[0], self.route.headings[0]
        t.lane[0] = self.route.lane_ids[0]
        self.table = t
        self._traffic_args: tuple | None = None  # (rng, table, kernel arguments), built by move_traffic
        asked = {"num_vehicles": cfg.num_vehicles, "num_parked": cfg.num_parked,
                 "num_pedestrians": cfg.num_pedestrians, "num_bicycles": cfg.num_bicycles}
        ends = populate(self, asked)
        warn_spawn_shortfall(self.town, asked, dict(zip(asked, np.diff(ends))))
        t.color[:] = self.rng.integers(0, 8, size=n)
        self.monitor = EventMonitor(self.town, self.route, cfg.dt)
        row = n_base
        for k, sc in enumerate(self.scenarios):
            rows = np.arange(row, row + sc.max_actors)
            t.scenario[rows] = k
            sc.setup(self, rows)
            row += sc.max_actors
        #: actor rows of the emergency vehicles (siren on) the scenarios expose (their
        #: ``emergency_rows``): observed as their own class, known to privileged agents
        self.emergency_rows = np.array(
            [int(r) for sc in self.scenarios for r in getattr(sc, "emergency_rows", ())], np.int64)
        self._object_kind = t.kind.copy()
        self.collisions = CollisionWorld(t, self.static_boxes)
        # infrastructure: placed from the town and the route only, never from the scenario list
        self.rsus: RSUSet = deploy(self.town, self.route)
        self.channel = Channel(self.channel_config, self.rng)
        self.tick = 0
        self.last_control = np.zeros(3)
        self.applied_control = self.last_control
        self.control_noise: tuple[float, float, float] | None = None
        self.last_events: list = []
        #: the last delivered message, ``channel.Delivery`` (sender, sent_tick, payload, format)
        self.inbox: tuple | None = None
        self.ended = False
        self.signals.release()  # a scenario's light override ends with its episode
        self.lane_signal = self.signals.lane_states(0.0)
        self.perceive()

    # ------------------------------------------------------------------ step
    def step(self, control: np.ndarray, rsu_message: dict | None = None) -> list:
        """Advance one tick (``config.dt`` s). See the module docstring for the order.

        Args:
            control: ``(3,)`` ego ``(throttle in [0, 1], steer in [-1, 1], brake in [0, 1])``;
                validated by the adapters (``spaces.validate_control``).
            rsu_message: the active RSU's message ``{"length", "payload", "format"}``
                (``channel.message_space``; ``None``: nothing sent).

        Returns:
            Events emitted during this tick (``infractions.EventMonitor``).
        """
        self._check_running()
        # 2. V2X: the active RSU's message is sent now and delivered after the latency
        if rsu_message is not None:
            self.channel.send_action(self.tick, int(max(self.active_rsu[0], 0)), rsu_message)
        else:
            self.channel.advance(self.tick)
        return self._advance(control)

    def step_builtin(self, control: np.ndarray) -> list:
        """:meth:`step` with the built-in RSU policy's message (:meth:`default_rsu_message`),
        packed by the world itself and so sent without being checked again (the gym and batched
        envs step this way)."""
        self._check_running()
        self.send_builtin()
        return self._advance(control)

    def send_builtin(self) -> None:
        """Step 2 of :meth:`step_builtin`: the built-in policy's message goes on the channel."""
        u = int(self.active_rsu[0])
        sender = max(u, 0)
        if HAVE_JIT:  # the message bytes in one kernel (the same bytes as pack_rows + encode_message)
            data = _NO_BYTES
            if self._sends_builtin():
                ch, t = self.channel, self.table
                check_header(sender, self.tick)
                x, y, _, yaw = self.rsus.pose[u].tolist()
                data = builtin_message_kernel(
                    self.rsu_vis[0], VISIBLE_THRESHOLD, t.pos, t.yaw, t.speed, self.object_classes(), t.length, t.width, t.height,
                    t.actor_id, x, y, yaw, self._max_rows, self.config.encoding == "float16", sender, self.tick,
                    ch.wire_code, ch.header_pad)
            if len(data):
                self.channel.send_encoded(self.tick, data)
            else:
                self.channel.send(self.tick, sender, 0, _NO_PAYLOAD)  # sends nothing, as an empty message
            return
        objs = self._builtin_objects()
        length = 0
        if objs is not None:
            cfg = self.config
            length, payload = pack_rows(objs, cfg.max_payload_floats, cfg.encoding)
        if length:
            self.channel.send_valid(self.tick, sender, length, payload)
        else:
            self.channel.send(self.tick, sender, 0, _NO_PAYLOAD)  # sends nothing, as an empty message

    def _check_running(self) -> None:
        if self.ended:
            raise StepError("step() called on a world that has ended or was never reset; call reset()")

    def _advance(self, control: np.ndarray) -> list:
        """Steps 3-8 of the tick (after the message is on the channel), stage by stage: the
        stages are separate methods so that ``batch.WorldBatch`` can run each one over all its
        worlds before the next (the same kernel back to back stays in the CPU's caches)."""
        self.move_traffic(control)
        for stage in TICK_STAGES:
            stage(self)
        return self.deliver()

    def move_traffic(self, control: np.ndarray) -> None:
        """Steps 3-4c: the ego (:meth:`move_ego`), the signals, NPC vehicles and bicycles, then
        pedestrians. With numba the signals come first (their state depends only on the time)
        and the rest is one kernel call (``jit_tick.traffic_tick_kernel``, through a one-world
        ``jit_batch.TrafficBatch`` that keeps its 79 arguments in typed lists)."""
        if not HAVE_JIT:
            self.move_ego(control)
            self.update_signals()
            self.move_followers()
            self.move_walkers()
            return
        throttle, steer, brake = self._take_control(control)
        self.update_signals()
        if self._traffic_one is None:
            self._traffic_one = TrafficBatch([self])
        if not self._traffic_one.step_one(throttle, steer, brake):
            c = self._traffic_consts()
            self._respawn = traffic_tick_kernel(throttle, steer, brake, c[0], self.lane_signal,
                                                *flat_plans(self.plans), c[1], ego_is_vehicle(self.table), c[2],
                                                *c[3:])

    def _traffic_consts(self) -> tuple:
        """``traffic_tick_kernel``'s arguments that hold for the whole episode: ``(bicycle params,
        the town has sidewalks, jaywalking probability per tick, *traffic.followers_args,
        *pedestrians.walkers_args)``, built on the first tick (again if the world's generator or
        table is replaced)."""
        t, cached = self.table, self._traffic_args
        if cached is None or cached[0] is not self.rng or cached[1] is not t:
            cfg = self.config
            cached = self._traffic_args = (self.rng, t, (
                self._bicycle_params, self.sidewalks.index is not None, cfg.jaywalk_prob * cfg.dt,
                *followers_args(t, self.town, self.rng, cfg.dt), *walkers_args(t, self.sidewalks, self.town.index)))
        return cached[2]

    def _take_control(self, control: np.ndarray) -> tuple[float, float, float]:
        """Keep the ego's position before its move (for ``check_events``) and ``control`` (the
        agent's command) as ``last_control``; returns the control the ego's dynamics apply,
        ``(throttle, steer, brake)`` as Python floats, also kept as ``applied_control``.

        The applied control is the command plus ``control_noise`` (offsets a scenario set during
        the previous tick's hooks, e.g. ControlLoss), clipped to the action ranges; without noise
        it is the command itself. Calling this again within a tick gives the same result (the
        noise is cleared only when the next tick's scenario hooks run, :meth:`run_scenarios`)."""
        if type(control) is np.ndarray and control.dtype == np.float64:
            throttle, steer, brake = control.tolist()
        else:
            throttle, steer, brake = (float(c) for c in control)
        self._old_pos = self.table.pos[0].tolist()  # (x, y) as Python floats
        self.applied_control = self.last_control = np.array((throttle, steer, brake))
        noise = self.control_noise
        if noise is not None:
            throttle = min(max(throttle + noise[0], 0.0), 1.0)
            steer = min(max(steer + noise[1], -1.0), 1.0)
            brake = min(max(brake + noise[2], 0.0), 1.0)
            self.applied_control = np.array((throttle, steer, brake))
        return throttle, steer, brake

    def move_ego(self, control: np.ndarray) -> None:
        """Step 3: the ego's kinematic bicycle under ``control``."""
        t = self.table
        throttle, steer, brake = self._take_control(control)
        old = self._old_pos
        if HAVE_JIT:
            x, y, yaw, v, a = bicycle_step_scalar(old[0], old[1], t.yaw[0], t.speed[0], throttle, steer, brake,
                                                  *self._bicycle_params)
        else:
            x, y, yaw, v, a = bicycle_step(t.pos[0, 0], t.pos[0, 1], t.yaw[0], t.speed[0], throttle, steer, brake,
                                           self.params, self.config.dt)
        t.pos[0] = (x, y)
        t.yaw[0], t.speed[0], t.accel[0] = yaw, v, a

    def update_signals(self) -> None:
        """Step 4a: the traffic lights' state at the end of this tick."""
        self.lane_signal = self.signals.lane_states((self.tick + 1) * self.config.dt)

    def move_followers(self) -> None:
        """Step 4b: NPC vehicles and bicycles (the rows to respawn are kept for step 5)."""
        t = self.table
        self._respawn = step_followers(t, self.town, self.lane_signal, self.rng, self.config.dt, t.pos[0], self.plans)

    def move_walkers(self) -> None:
        """Step 4c: pedestrians."""
        cfg = self.config
        step_walkers(self.table, self.sidewalks, self.rng, cfg.dt, cfg.jaywalk_prob)

    def run_scenarios(self) -> None:
        """Step 4d: each scenario's hook; step 5: respawns (scenario actors that reach the end of
        their plan leave the world). A hook may set ``control_noise`` for the ego's next move."""
        self.control_noise = None
        for sc in self.scenarios:
            sc.tick(self)
        if len(self._respawn):
            respawn_followers(self.table, self.town, self._drive_lanes, self.rng, self._respawn, 60.0)

    def check_events(self) -> None:
        """Step 6: collisions, infraction and route-progress events (``last_events``); pedestrians
        and cyclists hit by the ego leave the world ``infractions.HIT_VRU_LEAVES_S`` after the
        collision (``EventMonitor.leaving``); then the tick counter moves on."""
        self.last_events = self.monitor.update_world(self.tick + 1, self.table, self.collisions, self.lane_signal,
                                                     self._old_pos)
        for row in self.monitor.leaving(self.tick + 1):
            t = self.table
            t.active[row], t.speed[row], t.hold[row] = False, 0.0, False
        if self.scenarios:  # the progress just moved: a route's last scenario may be passed
            s = self.scenarios[0].ego_s(self)  # the same for every scenario
            for sc in self.scenarios:
                sc.check_passed(self, s)
        self.tick += 1

    def deliver(self) -> list:
        """Step 8: the channel delivers what is due into the ego's inbox; returns ``last_events``."""
        for msg in self.channel.deliver(self.tick):
            self.inbox = msg
        return self.last_events

    # ------------------------------------------------------------------ perception
    def occluders(self) -> Boxes:
        """All boxes that block sight: active actors (rows first) then static boxes."""
        t = self.table
        s = self.static_boxes
        n = len(t)
        return Boxes.trusted(
            np.concatenate([t.pos, s[:, :2]]), np.concatenate([t.length, s[:, 2]]),
            np.concatenate([t.width, s[:, 3]]), np.concatenate([t.yaw, s[:, 4]]),
            np.zeros(n + len(s)), np.concatenate([np.where(t.active, t.height, 0.0), self.static_heights]),
        )

    def perceive(self) -> None:
        """Step 7: visible fraction of every actor from the ego and from each active RSU
        (``active_rsu``, ``ego_vis``, ``rsu_vis``). With numba these arrays are the kernel's
        output buffers, overwritten by the next tick's call: copy them to keep them."""
        cfg, t = self.config, self.table
        if HAVE_JIT:  # one kernel call, through a one-world jit_batch.PerceiveBatch (1 argument, not 31)
            if self._perceive_one is None:
                self._perceive_one = PerceiveBatch([self])
            if not self._perceive_one.step_one():
                self.active_rsu, self.ego_vis, self.rsu_vis = perceive_all_kernel(*self._perceive_consts())
            return
        self.active_rsu = select_active(self.rsus, t.pos[0], float(t.yaw[0]), cfg.rsu_range, cfg.rsu_slots)
        boxes = self.occluders()
        n = len(t)
        targets = np.flatnonzero(t.active)
        targets = targets[targets > 0]
        self.ego_vis = np.zeros(n)
        ego_sensor = np.array([t.pos[0, 0], t.pos[0, 1], EGO_SENSOR_Z])
        near = targets[row_norms(t.pos[targets] - t.pos[0]) < cfg.ego_range]
        if len(near):
            self.ego_vis[near] = visible_fraction(ego_sensor, boxes, near, ignore=np.array([0]),
                                                  max_range=cfg.ego_range)
        self.rsu_vis = np.zeros((cfg.rsu_slots, n))
        self._rsu_perception(boxes, targets)

    def _perceive_consts(self) -> tuple:
        """``perceive_all_kernel``'s arguments (all hold for the episode: the kernel reads the
        table's columns in place, writes the actors' rows of its box workspace,
        ``jit_perception.perceive_workspace``, and its outputs, ``perceive_outputs``: the last three,
        which become ``active_rsu``, ``ego_vis`` and ``rsu_vis``), kept until the table or the RSUs
        change."""
        t, cfg = self.table, self.config
        cached = self._perceive_args
        if cached is None or cached[0] is not t or cached[1] is not self.rsus:
            cached = self._perceive_args = (t, self.rsus, (
                self.rsus.pose, FACING_MAX_ANGLE, LOOKAHEAD_M, VIEW_HALF_ANGLE,
                int(cfg.rsu_slots), t.pos, t.length, t.width, t.yaw, t.height, t.active,
                *perceive_workspace(len(t), self.static_boxes, self.static_heights, *self.static_trig,
                                    self._static_half_diag), EGO_SENSOR_Z,
                float(cfg.ego_range) ** 2, float(cfg.ego_range), float(cfg.rsu_range) ** 2, float(cfg.rsu_range),
                0.5 * RSU_HFOV, *VISIBILITY_SAMPLING, *perceive_outputs(len(t), int(cfg.rsu_slots))))
        return cached[2]

    def _rsu_perception(self, boxes: Boxes, targets: np.ndarray) -> None:
        cfg, t = self.config, self.table
        for k, u in enumerate(self.active_rsu):
            if u < 0:
                continue
            x, y, z, yaw = self.rsus.pose[u]
            near = targets[row_norms(t.pos[targets] - (x, y)) < cfg.rsu_range]
            if len(near):
                self.rsu_vis[k, near] = visible_fraction(np.array([x, y, z]), boxes, near, max_range=cfg.rsu_range,
                                                         sensor_yaw=yaw, hfov=RSU_HFOV)

    # ------------------------------------------------------------------ helpers
    def rsu_objects(self, slot: int = 0) -> np.ndarray:
        """Objects the RSU in ``slot`` sees, in its frame: ``(K, 10)`` rows of
        ``channel.OBJECT_FIELDS`` sorted by distance to the unit."""
        u = self.active_rsu[slot]
        t = self.table
        if u < 0:
            return np.zeros((0, 10), np.float32)
        x, y, _, yaw = self.rsus.pose[u]
        if HAVE_JIT:
            return seen_rows_kernel(self.rsu_vis[slot], VISIBLE_THRESHOLD, t.pos, t.yaw, t.speed,
                                    self.object_classes(), t.length, t.width, t.height, t.actor_id, float(x),
                                    float(y), float(yaw))
        seen = np.flatnonzero(self.rsu_vis[slot] >= VISIBLE_THRESHOLD)
        return object_rows(t, seen, np.array([x, y]), yaw, self.object_classes())

    def object_classes(self) -> np.ndarray:
        """The class every actor row is observed as (object lists, RSU messages, BEV, camera
        semantics): ``table.kind``, except :data:`~.classes.EMERGENCY_VEHICLE` for the scenarios'
        emergency vehicles (their ``emergency_rows``, siren on). Worlds without one return
        ``table.kind`` itself; otherwise one array per episode, refreshed in place by each call."""
        if not len(self.emergency_rows):
            return self.table.kind
        np.copyto(self._object_kind, self.table.kind)
        self._object_kind[self.emergency_rows] = EMERGENCY_VEHICLE
        return self._object_kind

    def default_rsu_message(self) -> dict:
        """The built-in ``share_objects`` policy: pack what the RSU sees (or send nothing)."""
        objs = self._builtin_objects()
        if objs is None:
            return empty_message(self.channel_config)
        length, payload = pack_objects(objs, self.config.max_payload_floats, self.config.encoding)
        return {"length": length, "payload": payload, "format": FORMAT_OBJECTS}

    def _builtin_objects(self) -> np.ndarray | None:
        """What the built-in policy sends: the slot-0 RSU's object rows (``None``: nothing)."""
        return self.rsu_objects(0) if self._sends_builtin() else None

    def _sends_builtin(self) -> bool:
        """The built-in policy sends this tick: it is on and a unit serves slot 0."""
        return self.config.rsu_policy != "none" and self.active_rsu[0] >= 0

    def is_route_complete(self) -> bool:
        """The ego has passed the last route point (within 3 m)."""
        return self.monitor.progress >= len(self.route.points) - 3


def _half_diagonals(boxes: np.ndarray) -> np.ndarray:
    """Half diagonals of ``(S, 5)`` boxes, as the perception kernel computes them (numba path only)."""
    if not HAVE_JIT:
        return np.zeros(0)
    return half_diagonals_kernel(np.ascontiguousarray(boxes[:, 2]), np.ascontiguousarray(boxes[:, 3]))


#: the stages of a tick between the traffic's move (steps 3-4c) and the delivery (step 8), in order
TICK_STAGES = (World.run_scenarios, World.check_events, World.perceive)


__all__ = ["World", "StepError", "TICK_STAGES", "object_rows"]
