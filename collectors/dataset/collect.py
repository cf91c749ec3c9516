"""Expert data collection: the expert drives suite routes with recovery noise; every tick is recorded.

``collect(CollectConfig(suite="train"), "data/v2x", workers=2)`` runs one episode per (route, seed
index) job of the suite (``collectors.jobs``: same ids and world seeds as the evaluation harness),
each episode into one shard (:mod:`.shards`), recorded at 10 Hz (:mod:`.record`) with keyframe
facts and the seven camera images every ``KEYFRAME_EVERY`` ticks (:mod:`..chat.facts`).

An episode that raises (world or expert) is recorded under ``failed`` in the manifest with its
error, and the others go on; a later run retries it. Resuming: running again on the same root skips finished shards, removes temporary folders of
interrupted episodes and re-runs them from their seed; episodes are deterministic (world seed,
expert, perturbation seed), so a resumed collection has the same content as an uninterrupted one.
The settings are stored in ``manifest.json`` and must match on resume. The manifest's
``sensor_config`` is the sensor configuration of the recorded frames in ``EnvConfig`` terms
(``config.SENSOR_FIELDS``: ``camera_size`` = ``--camera-size``, ``camera_images`` = the images of
``--sensors``, ``lidar_scale`` = ``--lidar-scale``): ``gym.make(..., obs_mode="sensors",
**manifest["sensor_config"])`` gives an agent the images the data set holds, of the same shapes.

Scales (``SCALES``): ``tiny`` (3 routes x 1 seed, 150 ticks each: a smoke test), ``default``
(every route of the suite once: 52.7K frames and 50.9K QA pairs for ``train``, measured) and
``paper`` (2 seeds per route: 120 episodes, about 105K frames and 100K QA pairs, near the paper's
140K frames / 88K QA;
our routes are longer than the paper's ~500 runs of ~28 s). Measured sizes and times: README.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import time
import zlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from v2xbench.files import atomic_write_json, check_output_dir, remove_stale_tmp
from v2xbench.locks import dir_lock

from .. import jobs as J
from ..agent_fingerprint import legacy_match
from .parent_watch import exit_with_parent
from .perturb import PerturbConfig, Perturber
from .record import (
    DEFAULT_SENSORS,
    SENSORS,
    RecordConfig,
    frame_record,
    nav_command,
    record_schema,
)
from .shards import (
    MANIFEST_FORMAT,
    clear_temp,
    finish_shard,
    finished_shards,
    load_manifest,
    temp_shard,
)

MAX_SEEDS = 1000
MAX_CAMERA_SIDE = 2048  # pixels per camera side (7 cameras are stored every tick)
MAX_WORKERS = 256
SCALES = {
    "tiny": {"seeds": 1, "max_routes": 3, "max_ticks": 150},
    "default": {"seeds": 1, "max_routes": None, "max_ticks": None},
    "paper": {"seeds": 2, "max_routes": None, "max_ticks": None},
}


@dataclass(frozen=True)
class CollectConfig:
    """What to collect (stored in the manifest; a resume must use the same).

    Attributes:
        suite: route suite (``train``, ``val``, ``test50`` or a suite JSON path).
        seeds: seed indices per route. max_routes: only the first N routes (``None``: all).
        first_seed: the first seed index (episodes ``<route>_s<first_seed>`` on): another
            collection of the same routes with other world seeds, whose shards a
            ``data merge`` can join to this one's (:mod:`.merge`).
        max_ticks: cap per episode (``None``: the route's time budget, ``episode.time_budget_steps``).
        sensors: stored every tick (``record.SENSORS``); keyframe images are always written.
        camera_size: ``(width, height)`` of the 7 cameras (``EnvConfig.camera_size``).
        lidar_scale: fraction of the default LiDAR channels and azimuths
            (``EnvConfig.lidar_scale``; GT visibility uses the LiDARs; < 1 is faster and coarser).
        perturb: inject recovery noise (:mod:`.perturb`).
        max_boxes: rows per GT box set. keyframe_every: ticks between keyframes.
        val_fraction: share of routes held out as ``val`` (by a hash of the route id).
        env: ``EnvConfig`` overrides (e.g. ``{"num_vehicles": 10}``).
        driver: an agent that drives instead of the expert, which still labels every frame
            (:mod:`.driver`, DAgger); ``None``: the expert drives.
        driver_config: the driver's keyword arguments.
        expert_share: share of the ticks on which the expert's control executes instead of the
            driver's (DAgger's beta; only with a driver).
    """

    suite: str = "train"
    seeds: int = 1
    first_seed: int = 0
    max_routes: int | None = None
    max_ticks: int | None = None
    sensors: tuple[str, ...] = DEFAULT_SENSORS
    camera_size: tuple[int, int] = (128, 64)
    lidar_scale: float = 1.0
    perturb: bool = True
    max_boxes: int = 96
    keyframe_every: int = 10
    val_fraction: float = 0.1
    env: dict = field(default_factory=dict)
    objects_obs: bool = True
    driver: str | None = None
    driver_config: dict = field(default_factory=dict)
    expert_share: float = 0.0

    def __post_init__(self) -> None:
        from .driver import check_driver_args

        check_driver_args(self.driver, self.driver_config, self.expert_share)
        if not isinstance(self.suite, str) or not self.suite:
            raise ValueError(f"CollectConfig: suite={self.suite!r} must be a suite name or path")
        if isinstance(self.sensors, str) or not all(isinstance(x, str) for x in self.sensors):
            raise ValueError(f"CollectConfig: sensors={self.sensors!r} must be a list of names")
        RecordConfig(tuple(self.sensors), self.max_boxes, self.objects_obs)  # validates all
        _positive_int("seeds", self.seeds, MAX_SEEDS)
        if not _is_int(self.first_seed) or not 0 <= self.first_seed <= MAX_SEEDS:
            raise ValueError(f"CollectConfig: first_seed={self.first_seed!r} must be an int in "
                             f"[0, {MAX_SEEDS}]")
        _positive_int("max_routes", self.max_routes, None, none_ok=True)
        _positive_int("max_ticks", self.max_ticks, None, none_ok=True)
        _positive_int("keyframe_every", self.keyframe_every, None)
        v = self.val_fraction
        if not (_is_real(v) and 0.0 <= v < 1):
            raise ValueError(f"CollectConfig: val_fraction={v!r} must be a number in [0, 1)")
        self.sensor_config()  # camera_size and lidar_scale by the EnvConfig fields' rules
        size = self.camera_size
        if (isinstance(size, str) or len(size) != 2 or not all(_is_int(v) for v in size)
                or not all(8 <= v <= MAX_CAMERA_SIDE for v in size)):
            raise ValueError(f"CollectConfig: camera_size={size!r} must be (width, height), each "
                             f"an int in [8, {MAX_CAMERA_SIDE}]")
        if not isinstance(self.perturb, bool):
            raise ValueError(f"CollectConfig: perturb={self.perturb!r} must be true or false")
        if not isinstance(self.env, dict):
            raise ValueError(f"CollectConfig: env={self.env!r} must be a dict of EnvConfig fields")
        bad = {"suite", "route_index", "obs_mode", "town"} & set(self.env)
        if bad:
            raise ValueError(f"CollectConfig: env keys {sorted(bad)} are chosen by the collector")
        from v2xbench.envs.v2x_intersection.sim.config import SENSOR_FIELDS, make_config

        bad = set(SENSOR_FIELDS) & set(self.env)
        if bad:
            raise ValueError(f"CollectConfig: env keys {sorted(bad)} are the collector's sensor "
                             "settings: give them as camera_size, sensors and lidar_scale "
                             "(--camera-size, --sensors, --lidar-scale)")

        try:
            make_config(obs_mode="objects", **self.env)  # up front, not in the first episode
        except (TypeError, ValueError) as e:
            raise ValueError(f"CollectConfig: env: {e}") from None

    @classmethod
    def from_json(cls, d: dict) -> CollectConfig:
        """The config stored in a manifest (:meth:`to_json`); unknown or bad fields raise
        ``ValueError`` naming them."""
        if not isinstance(d, dict):
            raise ValueError(f"CollectConfig: {type(d).__name__} is not a JSON object")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"CollectConfig: unknown fields {unknown}")
        kw = dict(d)
        kw.setdefault("objects_obs", False)  # data sets from before obs/* was recorded
        for k in ("sensors", "camera_size"):
            if isinstance(kw.get(k), list):
                kw[k] = tuple(kw[k])
        return cls(**kw)

    def sensor_config(self) -> dict:
        """The sensor configuration of the recorded frames as ``EnvConfig`` fields
        (``config.sensor_config``: ``camera_size``, ``camera_images`` = the images of
        ``sensors``, ``lidar_scale``), stored in the manifest.

        Raises:
            ValueError: ``camera_size`` or ``lidar_scale`` breaks its ``EnvConfig`` rule.
        """
        from v2xbench.envs.v2x_intersection.sim.config import (
            CAMERA_IMAGES,
            make_config,
            sensor_config,
        )

        if isinstance(self.camera_size, str):  # the env would read "128x64"; the collector does not
            raise ValueError(f"CollectConfig: camera_size={self.camera_size!r} must be (width, "
                             "height)")
        images = tuple(k for k in CAMERA_IMAGES if k in self.sensors)
        try:
            cfg = make_config(camera_size=self.camera_size, camera_images=images,
                              lidar_scale=self.lidar_scale)
        except ValueError as e:
            raise ValueError(f"CollectConfig: {e}") from None
        return sensor_config(cfg)

    def record_schema(self) -> dict[tuple[str, ...], tuple]:
        """``record.record_schema`` of the frames these settings record (every key, dtype and
        per-frame shape a shard's memmap holds)."""
        from v2xbench.envs.v2x_intersection.sim.config import make_config

        ego, rsu = _lidar_specs(self)
        env = make_config(**self.env)
        return record_schema(RecordConfig(tuple(self.sensors), self.max_boxes, self.objects_obs),
                             tuple(self.camera_size), env.route_points,
                             (ego.max_points, rsu.max_points), _bev_spec().size, env.max_objects,
                             env.max_payload_floats)

    def to_json(self) -> dict:
        """JSON-compatible dict (tuples as lists)."""
        d = dataclasses.asdict(self)
        d["sensors"], d["camera_size"] = list(self.sensors), list(self.camera_size)
        return d

    @classmethod
    def for_scale(cls, scale: str, **overrides) -> CollectConfig:
        """A config of a named scale (``SCALES``), with explicit overrides winning."""
        if scale not in SCALES:
            raise ValueError(f"unknown scale {scale!r}; known: {', '.join(SCALES)}")
        kw = dict(SCALES[scale])
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**kw)


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _positive_int(name: str, v, most: int | None, none_ok: bool = False) -> None:
    if v is None and none_ok:
        return
    if not _is_int(v) or v < 1 or (most is not None and v > most):
        span = f"in [1, {most}]" if most is not None else ">= 1"
        raise ValueError(f"CollectConfig: {name}={v!r} must be an int {span}"
                         + (" or None" if none_ok else ""))


def route_split(route_id: str, suite_split: str, val_fraction: float) -> str:
    """``train``, ``val`` or ``test`` for a route: val suites are val, test suites (``test``,
    ``test50``) test; train routes are held out by hash."""
    if suite_split in ("val", "test"):
        return suite_split
    if suite_split.startswith("test"):  # test50.json's split is its name
        return "test"
    return "val" if (zlib.crc32(route_id.encode()) % 1000) < 1000 * val_fraction else "train"


def _lidar_specs(cfg: CollectConfig):
    """The ego and the RSU LiDAR specs of ``cfg`` (``lidar_scale``, as ``EnvConfig``'s)."""
    from v2xbench.envs.v2x_intersection.sensors.lidar import scaled_lidar_specs

    return scaled_lidar_specs(cfg.lidar_scale)


def _bev_spec():
    from v2xbench.envs.v2x_intersection.sensors import BevSpec

    return BevSpec(privileged=True)  # ground truth: every actor


def _rig(cfg: CollectConfig):
    from v2xbench.envs.v2x_intersection.sensors import SensorConfig, SensorRig

    ego, rsu = _lidar_specs(cfg)
    return SensorRig(SensorConfig(
        camera_size=tuple(cfg.camera_size), rsu_camera_size=tuple(cfg.camera_size),
        ego_lidar=ego, rsu_lidar=rsu, bev=_bev_spec() if "bev" in cfg.sensors else None))


def _stack(rows: list[dict]) -> dict:
    """Stack a list of nested dicts of arrays along a new first axis."""
    out = {}
    for k, v in rows[0].items():
        out[k] = _stack([r[k] for r in rows]) if isinstance(v, dict) else np.stack([r[k] for r in rows])
    return out


def _save_images(frame: dict, tmp: Path, root_rel: str, tick: int) -> dict[str, str]:
    from PIL import Image

    from .record import CAMERAS

    (tmp / "images").mkdir(exist_ok=True)
    out = {}
    for cam in CAMERAS:
        name = f"t{tick:05d}_{cam}.png"
        Image.fromarray(frame["cameras"][cam]["rgb"]).save(tmp / "images" / name, optimize=False)
        out[cam] = f"{root_rel}/images/{name}"
    return out


def _drive(cfg, world, expert, tracker, cap, rig, rcfg, perturber, tmp, rel, episode,
           driver=None, share=None):
    """Step one episode; returns ``(frame records, keyframe facts, how it ended)``. With a
    ``driver`` (:class:`.driver.LearnedDriver`) it drives and the expert labels; ``share``: the
    stream that picks the ticks the expert's control executes (:func:`.driver.share_stream`)."""
    from ..chat.facts import keyframe_facts

    rows, keyframes = [], []
    history: dict = {"speed": {}, "command": {}}
    ended = "max_ticks"
    wants_info = driver is not None and driver.info_style is not None  # its act takes info
    info = tracker.info() if wants_info else None
    while True:
        control = expert.act(None)  # the label of this tick (and the expert's own control)
        if driver is not None:  # called every tick (its state follows the drive); one draw a tick
            mine, expert_turn = driver.act(world, info), share.random() < cfg.expert_share
            control = control if expert_turn else mine
        frame = rig.capture(world)
        executed, noisy = perturber.apply(world.tick, control, float(world.table.speed[0]),
                                          expert.last_plan.reason)
        rows.append(frame_record(world, frame, expert, executed, noisy, rcfg))
        history["speed"][world.tick] = float(world.table.speed[0])
        history["command"][world.tick] = nav_command(world)
        if world.tick % cfg.keyframe_every == 0:
            images = _save_images(frame, tmp, rel, world.tick)
            keyframes.append(keyframe_facts(world, frame, expert, history, images, episode))
        if world.tick >= cap:
            break
        events = world.step_builtin(executed) if driver is None else driver.step(world, executed)
        _, term, trunc, info = tracker.after_step(events, with_info=wants_info)
        if world.is_route_complete():
            ended = "route_complete"
        elif term or trunc:
            ended = "terminated" if term else "truncated"
        if ended != "max_ticks":  # record the final state too
            control = expert.act(None)
            frame = rig.capture(world)
            rows.append(frame_record(world, frame, expert, control, False, rcfg))
            break
    return rows, keyframes, ended


def run_episode(cfg: CollectConfig, job: J.Job, root: str | Path) -> dict:
    """Drive one job with the expert and write its shard; returns the shard's metadata."""
    import torch
    from tensordict import TensorDict
    from v2xbench.agents.expert import Expert
    from v2xbench.envs.v2x_intersection.evaluation.episode import EpisodeTracker
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    spec = load_suite_cached(cfg.suite)[job.route_index]
    seed = J.job_seed(spec.seed, job.seed_index)
    driver, share = None, None
    env = {"obs_mode": "objects", **cfg.env}
    if cfg.driver is not None:
        from .driver import LearnedDriver, share_stream

        driver, share = LearnedDriver(cfg.driver, cfg.driver_config, cfg.env), share_stream(seed)
        env = driver.overrides
    world = World(make_config(town=spec.town, **env))
    world.reset(seed=seed, spec=spec)
    expert = Expert()
    expert.bind(world)
    expert.reset({})
    if driver is not None:
        driver.reset(world, spec.town, seed)
    tracker = EpisodeTracker(world)
    cap = tracker.max_steps if cfg.max_ticks is None else min(cfg.max_ticks, tracker.max_steps)
    rig = _rig(cfg)
    rcfg = RecordConfig(tuple(cfg.sensors), cfg.max_boxes, cfg.objects_obs)
    perturber = Perturber(PerturbConfig() if cfg.perturb else None, seed, world.config.dt)
    tmp = temp_shard(root, job.job_id)
    rel = f"shards/{job.job_id}"
    episode = {"episode": job.job_id, "route_id": spec.id, "town": spec.town,
               "scenarios": [s.type for s in spec.scenarios]}
    try:
        rows, keyframes, ended = _drive(cfg, world, expert, tracker, cap, rig, rcfg, perturber, tmp, rel,
                                        episode, driver, share)
    except Exception:
        shutil.rmtree(tmp, ignore_errors=True)  # a failed episode leaves nothing behind
        raise
    data = _stack(rows)
    td = TensorDict(data, batch_size=[len(rows)])
    td.memmap_(tmp / "data")
    with open(tmp / "keyframes.jsonl", "w") as f:
        for k in keyframes:
            f.write(_json_line(k))
    from v2xbench.envs.v2x_intersection.evaluation.infractions import EVENT_NAMES

    counts = world.monitor.counts
    meta = {
        "suite": cfg.suite, "route_id": spec.id, "route_index": job.route_index,
        "seed_index": job.seed_index, "seed": seed, "town": spec.town, "weather": spec.weather,
        "time_of_day": spec.time_of_day, "scenarios": episode["scenarios"], "frames": len(rows),
        "keyframes": len(keyframes), "ended_by": ended,
        "split": route_split(spec.id, _suite_split(cfg.suite), cfg.val_fraction),
        "route_completion": round(float(world.monitor.route_completion), 3),
        "infractions": {EVENT_NAMES[i]: int(n) for i, n in enumerate(counts) if n},
        "perturbations": [list(e) for e in perturber.events],
        "route": np.round(world.route.points, 2).tolist(),
    }
    finish_shard(tmp, root, job.job_id, meta)
    return dict(meta, wall_s=round(time.perf_counter() - t0, 2))


def _json_line(obj) -> str:
    import json

    return json.dumps(obj, sort_keys=True) + "\n"


def _suite_split(suite: str) -> str:
    import json

    from v2xbench.envs.v2x_intersection.suites.route_files import SUITE_DIR

    path = SUITE_DIR / f"{suite}.json" if (SUITE_DIR / f"{suite}.json").exists() else Path(suite)
    return str(json.loads(Path(path).read_text()).get("split", "train"))


def _summary(meta: dict) -> dict:
    keys = ("route_id", "seed_index", "town", "frames", "keyframes", "split", "ended_by",
            "route_completion", "scenarios", "wall_s")
    return {k: meta.get(k) for k in keys}


def _check_run(root: Path, workers, max_episodes) -> None:
    """Arguments of :func:`collect` that the config does not cover, checked before any work."""
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= MAX_WORKERS:
        raise ValueError(f"collect: workers={workers!r} must be an int in [1, {MAX_WORKERS}]")
    if max_episodes is not None and (isinstance(max_episodes, bool) or not isinstance(
            max_episodes, int) or max_episodes < 1):
        raise ValueError(f"collect: max_episodes={max_episodes!r} must be an int >= 1 or None")
    check_output_dir(root, "collect output")


def collect(cfg: CollectConfig, root: str | Path, workers: int = 1, progress: bool = True,
            max_episodes: int | None = None) -> dict:
    """Collect (or resume) a data set at ``root``; returns the manifest.

    Holds ``v2xbench.locks.dir_lock`` on ``root`` for the whole run (a second collect into the
    same folder is refused, naming the holder). Worker processes end when this process dies
    (:mod:`.parent_watch`).

    Args:
        cfg: what to collect. root: data set folder.
        workers: episode processes (1: in this process).
        progress: show a progress bar (episodes, with frames so far).
        max_episodes: stop after this many new episodes (the rest stays pending; run again to
            resume).

    Raises:
        ValueError: a bad argument, ``root`` is in use by another run (``DirectoryLocked``) or
            holds a data set collected with other settings (or another driver), a driver that
            cannot drive (:class:`.driver.LearnedDriver`).
    """
    from v2xbench.envs.v2x_intersection.suites.route_files import load_suite_cached

    root = Path(root)
    _check_run(root, workers, max_episodes)
    routes = load_suite_cached(cfg.suite)
    jobs = [j for j in J.make_jobs([r.id for r in routes], cfg.first_seed + cfg.seeds,
                                   cfg.max_routes) if j.seed_index >= cfg.first_seed]
    driver = None
    if cfg.driver is not None:  # built once here: a bad driver is refused before any episode
        from .driver import LearnedDriver

        driver = LearnedDriver(cfg.driver, cfg.driver_config, cfg.env).identity()
    with dir_lock(root, "collect"):
        return _collect_locked(cfg, root, jobs, workers, progress, max_episodes, driver)


def _stored_config(d) -> dict:
    """A manifest's config as :meth:`CollectConfig.to_json` writes it today (fields added since
    it was written read as their defaults; one that does not read comes back as stored)."""
    if not isinstance(d, dict):
        return {}
    try:
        return CollectConfig.from_json(d).to_json()
    except ValueError:
        return d


def _start_manifest(cfg: CollectConfig, root: Path, jobs: list,
                    driver: dict | None) -> tuple[dict, dict]:
    """The manifest at the start of a run (after clearing an interrupted one's leftovers) and
    the finished shards (``driver``: :func:`.driver.driver_identity` or ``None``)."""
    if (root / "manifest.json").exists():
        old = load_manifest(root)
        if "merged_from" in old:
            raise ValueError(f"{root} is a merged data set (v2xbench data merge); collect into "
                             "its sources or another --out")
        was = _stored_config(old.get("config"))
        if was != cfg.to_json():
            diff = {k: (was.get(k), v) for k, v in cfg.to_json().items() if was.get(k) != v}
            raise ValueError(f"{root} was collected with other settings (old, new): {diff}; "
                             "use another --out or the same settings")
        was_driver = old.get("driver")
        if was_driver != driver and not (was_driver and driver and legacy_match(was_driver, driver)):
            raise ValueError(f"{root} was driven by another driver or other weights (old, new): "
                             f"{old.get('driver')}, {driver}; use another --out or the same "
                             "driver")
        shard_info = dict(old.get("shards", {}))
    else:
        shard_info = {}
    clear_temp(root)  # safe: the lock says no other collect writes here
    remove_stale_tmp(root)
    done = finished_shards(root)
    for sid, meta in done.items():
        shard_info.setdefault(sid, _summary(meta))
    manifest = {"format": MANIFEST_FORMAT, "config": cfg.to_json(),
                "sensor_config": cfg.sensor_config(),
                "episodes": [j.job_id for j in jobs],
                "shards": {k: v for k, v in shard_info.items() if k in done}, "failed": {}}
    if driver is not None:
        manifest["driver"] = driver
    return manifest, done


def _write_manifest(manifest: dict, root: Path) -> None:
    atomic_write_json(root / "manifest.json", manifest, indent=1, sort_keys=True)


def _collect_locked(cfg: CollectConfig, root: Path, jobs: list, workers: int, progress: bool,
                    max_episodes: int | None, driver: dict | None) -> dict:
    manifest, done = _start_manifest(cfg, root, jobs, driver)
    _write_manifest(manifest, root)
    todo = [j for j in jobs if j.job_id not in done]
    if max_episodes is not None:
        todo = todo[:max_episodes]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), initial=len(done.keys() & {j.job_id for j in jobs}),
                   unit="episode", desc="collect")

    def record(meta: dict) -> None:
        manifest["shards"][meta["episode"]] = _summary(meta)
        manifest["failed"].pop(meta["episode"], None)
        _write_manifest(manifest, root)
        if bar is not None:
            frames = sum(s["frames"] for s in manifest["shards"].values())
            bar.update(1)
            bar.set_postfix(frames=frames)

    def failed(job: J.Job, e: BaseException) -> None:
        manifest["failed"][job.job_id] = f"{type(e).__name__}: {e}"
        _write_manifest(manifest, root)
        if bar is not None:
            bar.update(1)

    if workers <= 1 or len(todo) <= 1:
        for job in todo:
            try:
                meta = run_episode(cfg, job, root)
            except Exception as e:  # noqa: BLE001  (a failed episode is recorded; the rest go on)
                failed(job, e)
                continue
            record(dict(meta, episode=job.job_id))
    else:
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"),
                                 initializer=exit_with_parent, initargs=(os.getpid(),)) as ex:
            futs = {ex.submit(run_episode, cfg, job, str(root)): job for job in todo}
            for fut in as_completed(futs):
                try:
                    meta = fut.result()
                except Exception as e:  # noqa: BLE001  (incl. a dead worker: BrokenProcessPool)
                    failed(futs[fut], e)
                    continue
                record(dict(meta, episode=futs[fut].job_id))
    if bar is not None:
        bar.close()
    manifest["complete"] = all(j.job_id in manifest["shards"] for j in jobs)
    _write_manifest(manifest, root)
    return manifest


__all__ = ["MAX_CAMERA_SIDE", "MAX_SEEDS", "MAX_WORKERS", "SCALES", "SENSORS", "CollectConfig",
           "collect", "route_split", "run_episode"]
