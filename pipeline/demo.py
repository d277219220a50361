"""The main job end to end (``dng demo``): run the project's stages and write the report."""

from __future__ import annotations

import json
import multiprocessing
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from threadpoolctl import threadpool_limits

from core.errors import InputError
from core.fileio import atomic_open, write_json
from core.progress import StageEta
from core.project import RECORD_NAME, Project
from core.sim.sanity import not_standing
from pipeline.config import (
    Log,
    PipelineConfig,
    available_extra_motions,
    available_test_motions,
    available_validation_motions,
    joint2coarse_config,
    renderer_config,
    renderer_validation_motion,
)
from pipeline.deviations import as_json as deviations_json
from pipeline.deviations import deviations_markdown, from_json, methods_markdown
from pipeline.provenance import provenance
from pipeline.stages.ablations import stage_ablation
from pipeline.stages.baselines import stage_baselines
from pipeline.stages.dataset import stage_dataset, stage_testset
from pipeline.stages.evaluate import eval_motions, ours_to_dnr, stage_eval, stage_eval_motion
from pipeline.stages.garment import stage_garment
from pipeline.stages.joint2coarse import stage_joint2coarse
from pipeline.stages.motions import stage_motions
from pipeline.stages.proxy import stage_proxy
from pipeline.stages.renderer import stage_renderer
from pipeline.stages.simulate import stage_embedding, stage_simulate
from pipeline.stages.videos import stage_videos

#: Seconds per unit of work of each stage on the 2-core development machine, measured on quick
#: runs (docs/decisions.md, "_SECONDS_PER"). Only their ratios matter once a stage has run: the
#: time left is the remaining work at the rate measured so far.
_SECONDS_PER = {
    "motion": 0.26,  # the motions stage, per motion
    "setup": 2.5,  # garment, proxy: per stage
    # proxy simulation at 8 x 16, Chebyshev-accelerated: per clip (set-up, lead-in) and per frame
    "sim_clip": 4.0,
    "sim_frame": 0.10,
    # the implicit solver at 2 steps a frame (quick's), per frame beside sim_clip per clip
    "implicit_frame": 0.135,
    # the detailed target embedded in the proxy's simulation and kept out of the body, per frame
    "embed_frame": 0.22,
    # the target bound to the proxy, once for every clip
    "embedding": 30.0,
    "target_frame": 23.0,  # the target simulated as cloth, per frame
    # the embedded target's tiers simulated on it (and again for the floor), per frame
    "tiers_frame": 2.0,
    # ground-truth renders per training sample (3 frames) at 128 px
    "gt_sample": 0.25,
    # Joint2Coarse, per step of the paper's model (ours trains first)
    "j2c_step": 0.035,
    # test-set ground truth per sample at 128 px
    "test_sample": 0.40,
    # renderer step at 128 px, the baselines training beside it
    "render_step": 0.73,
    # evaluation per test sample and method (each proxy counts), the videos beside it
    "eval_sample": 0.16,
    "video_frame": 0.34,  # videos, per frame of a test motion
    "eval_report": 1.0,  # the evaluation's report, pooled from its motions' scores
}


def _mirror_markdown(mirror: dict | None) -> str:
    """The sentence the report gives the mirrored training clips (``mirror`` of Joint2Coarse's
    report; "" when the setting is off)."""
    if not mirror:
        return ""
    off = f"{mirror['asymmetry_mm']:.0f} mm of its {mirror['size_mm']:.0f} mm"
    if mirror["used"]:
        return f" Every training clip's left-right mirror too (the garment is symmetric to {off})."
    return (
        f" No mirrored clips: the garment is not left-right symmetric ({off}), though the "
        "settings ask for them."
    )


def stage_costs(config: PipelineConfig) -> list[float]:
    """Expected seconds of every stage ``run_demo`` runs, in its order (for the time left).

    The estimate scales the per-unit costs of :data:`_SECONDS_PER` by the preset's frames,
    samples, steps and image size.
    """
    c = _SECONDS_PER
    tests = available_test_motions(config)
    pixels = (config.image_size / 128) ** 2
    if config.sim_solver == "implicit":
        per_frame = c["implicit_frame"] * config.sim_substeps / 2
    else:
        per_frame = c["sim_frame"] * config.sim_substeps * config.sim_iterations / (8 * 16)

    def sim(frames: int) -> float:
        return c["sim_clip"] + per_frame * frames

    target = c["target_frame"] if config.target_mode == "simulate" else c["embed_frame"]
    tiered = config.target_mode == "tiers"

    def target_cost(frames: int) -> float:
        from core.sim.tiers import TierConfig  # scipy: not at the CLI's import

        floor = min(frames, TierConfig.floor_frames)
        return target * frames + (c["tiers_frame"] * (frames + floor) if tiered else 0.0)

    motions = [config.train_motion, *available_extra_motions(config)]
    motions += [*available_validation_motions(config), *tests]
    costs = [c["motion"] * len(motions)] + [c["setup"]] * 2
    embedded = config.simulate_target and config.target_mode != "simulate"
    costs += [c["embedding"]] if embedded else []
    costs += [sim(config.train_motion.frames)]
    costs += [target_cost(config.train_motion.frames)] if config.simulate_target else []
    costs += [sim(m.frames) for m in available_extra_motions(config)]
    costs += [sim(m.frames) for m in available_validation_motions(config)]
    costs += [sim(m.frames) for m in tests]
    validation = renderer_validation_motion(config) if config.simulate_target else None
    checked = [validation] if validation else []  # protocol V
    if config.simulate_target:
        costs += [target_cost(m.frames) for m in [*checked, *tests]]
        train_samples = -(-config.train_motion.frames // config.frame_stride)
        costs += [c["gt_sample"] * pixels * train_samples * config.views_per_frame]
        early, late = _share_sets(config)
        costs += [cost for _, cost in early]  # in the main lane after the training renders
    costs += [c["j2c_step"] * joint2coarse_config(config).total_steps]
    if config.simulate_target:  # in the order of the stage table: Joint2Coarse (beside the
        # training renders), our renderer, then the second lane's baselines and ground-truth
        # sets, which count their share of the wall time (with two lanes, half their seconds)
        render = c["render_step"] * pixels * renderer_config(config).steps
        costs += [render]
        # the baselines: three quarters of our renderer's seconds ("_SECONDS_PER")
        costs += [0.375 * render] if config.baselines else []
        costs += [0.5 * cost for _, cost in late]
        costs += [render] * len(config.ablations)
        # the evaluation's motions in the main lane, then the second lane's (the videos, then
        # its motions) at half share, then the report that pools them
        evaluation = _evaluation_costs(config)
        mine, theirs = _share_evaluation(config)
        costs += [evaluation[m] for m in mine]
        costs += [0.5 * _videos_cost(config)]
        costs += [0.5 * evaluation[m] for m in theirs]
        costs += [c["eval_report"]]
    return costs


def _share_sets(config: PipelineConfig) -> tuple[list[tuple[Job, float]], list[tuple[Job, float]]]:
    """The evaluation's ground-truth sets (:func:`stage_testset`: the renderers' validation
    motion's, then the test motions', then the training motion's) with their expected seconds:
    those the main lane can make after the training renders while Joint2Coarse still trains
    beside them, and the rest, which follow the baselines in the second lane."""
    c = _SECONDS_PER
    train = config.train_motion
    validation = renderer_validation_motion(config)
    sets: list[tuple[Job, object]] = [
        (("testset", f"validation set {validation.name} (cameras of its own)",
          (validation.name, "validation")), validation)
    ] if validation else []  # fmt: skip
    sets += [
        (("testset", f"test set {m.name}{' (the training motion)' if m is train else ''} "
          "(unseen cameras)", (m.name, "test")), m)
        for m in [*available_test_motions(config), train]
    ]  # fmt: skip
    pixels = (config.image_size / 128) ** 2
    samples = -(-train.frames // config.frame_stride) * config.views_per_frame
    main = c["gt_sample"] * pixels * samples  # the training renders
    room = c["j2c_step"] * joint2coarse_config(config).total_steps - main
    early, late = [], []
    for job, motion in sets:
        cost = c["test_sample"] * pixels * _test_samples(config, motion.frames)
        fits = cost <= room and not late  # in order: the lanes keep the sets' order
        (early if fits else late).append((job, cost))
        room -= cost if fits else 0.0
    return early, late


def _test_samples(config: PipelineConfig, frames: int) -> int:
    """Samples of a ground-truth set (:func:`stage_testset`) of a clip this long."""
    return -(-frames // config.test_stride) * config.test_views


def _videos_cost(config: PipelineConfig) -> float:
    """Expected seconds of the videos (:func:`stage_videos`)."""
    frames = sum(m.frames for m in available_test_motions(config))
    return _SECONDS_PER["video_frame"] * (config.image_size / 128) ** 2 * frames


def _evaluation_costs(config: PipelineConfig) -> dict[str, float]:
    """Expected seconds of each motion's evaluation (:func:`stage_eval_motion`)."""
    frames = {m.name: m.frames for m in [config.train_motion, *available_test_motions(config)]}
    validation = renderer_validation_motion(config)
    frames.update({validation.name: validation.frames} if validation else {})
    methods = 2 * (1 + len(config.baselines)) + len(config.ablations)
    per_sample = _SECONDS_PER["eval_sample"] * (config.image_size / 128) ** 2 * methods
    return {m: per_sample * _test_samples(config, frames[m]) for m in eval_motions(config)}


def _share_evaluation(config: PipelineConfig) -> tuple[list[str], list[str]]:
    """The evaluation's motions for the main lane and for the second, beside the videos: the
    costliest first, each to the lane with less expected work so far; each lane's in the
    evaluation's order."""
    costs = _evaluation_costs(config)
    load = [0.0, _videos_cost(config)]
    lanes: list[set[str]] = [set(), set()]
    for motion in sorted(costs, key=lambda m: -costs[m]):
        lane = 0 if load[0] <= load[1] else 1
        lanes[lane].add(motion)
        load[lane] += costs[motion]
    return [m for m in costs if m in lanes[0]], [m for m in costs if m in lanes[1]]


class _Progress:
    """Stage headers with elapsed time and an estimate of the time left.

    ``costs`` are the expected seconds of the stages in order (:func:`stage_costs`). The time
    left is :class:`core.progress.StageEta`'s: the remaining stages' cost at the pace of the
    stages that ran so far (a stage reused from an earlier run, done in under a tenth of its
    cost, does not set the pace); the nominal pace before any ran.
    """

    def __init__(self, costs: list[float], out=None, clock=time.perf_counter):
        self.eta = StageEta(costs, clock, default_pace=1.0, reused_below=0.1)
        # sys.stderr as it is now, not as it was at import (a test's captured stream, closed since)
        self.out, self.clock = (sys.stderr if out is None else out), clock
        self.start = self.eta.start
        self.stage_times: dict[str, float] = {}
        self.beside: list[str] = []  # stages that ran in a second process beside others

    def log(self, message: str) -> None:
        print(message, file=self.out, flush=True)

    def seconds_left(self) -> float:
        return self.eta.seconds_left()

    def finished(self, name: str, seconds: float, share: float, index: int | None = None) -> None:
        """A stage that ran in another process beside others took ``seconds`` of its own; the
        estimate counts ``share`` of them (its part of the wall time: ``seconds`` over the
        number running at once); ``index``: its place in the costs (default: the next)."""
        self.stage_times[name] = seconds
        self.eta.stage_done(share, index)
        elapsed = self.clock() - self.start
        self.log(
            f"[{self.eta.done}/{self.eta.total}] {name}: {seconds:.0f} s ({elapsed / 60:.1f} min "
            f"in, about {self.seconds_left() / 60:.1f} min left)"
        )

    def stage(self, name: str, fn: Callable[[], object]) -> object:
        elapsed = self.clock() - self.start
        left = f", about {self.seconds_left() / 60:.1f} min left"
        self.log(f"[{self.eta.done + 1}/{self.eta.total}] {name} ({elapsed / 60:.1f} min in{left})")
        t0 = self.clock()
        result = fn()
        seconds = self.clock() - t0
        self.stage_times[name] = seconds
        self.eta.stage_done(seconds)
        return result


def _sim_bar(desc: str):
    """A tqdm bar fed by the simulator's (done, total) progress callback."""
    from tqdm import tqdm

    bar = {"bar": None}

    def update(done: int, total: int) -> None:
        if bar["bar"] is None:
            bar["bar"] = tqdm(total=total, desc=desc, unit="frame", leave=False)
        bar["bar"].n = done
        bar["bar"].refresh()
        if done >= total:
            bar["bar"].close()

    return update


#: The stage table's name of :func:`stage_embedding`.
EMBEDDING_STAGE = "embedding (the target bound to the proxy)"

#: Simulations run at once where there is a core for each (warp's CPU kernels use one thread).
SIM_PROCESSES = 2


def _baselines(project: Project, config: PipelineConfig, log: Log) -> dict:
    return stage_baselines(project, config, log, progress=False)


def _testset(project: Project, config: PipelineConfig, motion: str, check: str, log: Log) -> Path:
    """A ground-truth set: the renderers' validation motion's (``check == "validation"``,
    cameras of its own) or a test motion's."""
    return stage_testset(project, config, motion, log, validation=check == "validation")


#: The stages a spawned process may run (:func:`_stage_worker`): each needs only what is on disk.
_CHILD_STAGES: dict[str, Callable] = {
    "simulate": stage_simulate,
    "joint2coarse": stage_joint2coarse,
    "baselines": _baselines,
    "testset": _testset,
    "eval_motion": stage_eval_motion,
    "videos": stage_videos,
}


def blas_threads(threads: int) -> threadpool_limits:
    """numpy's and scipy's BLAS on ``threads`` threads in this process until the returned
    context exits, as torch is on ``torch_threads``: the demo gives each of its processes a
    core, and BLAS's own threads (one per core by default) would spin on the other process's.
    The frill tiers' simulation, two at a time, ran 1.3x faster on one BLAS thread each
    (docs/decisions.md, "BLAS on ``torch_threads``")."""
    import scipy.linalg  # noqa: F401  (scipy loads a BLAS of its own: limit it too)

    return threadpool_limits(threads, user_api="blas")


def _stage_worker(
    stage: str, root: str, params: dict, *args: str
) -> tuple[float, list[str], object]:
    """Child-process entry: one stage of :data:`_CHILD_STAGES` of a project (``args``: the
    stage's own, e.g. a simulation's motion and ``"proxy"`` | ``"target"``); its seconds, log
    lines and result."""
    lines: list[str] = []
    start = time.perf_counter()
    project, config = Project(root), PipelineConfig.from_params(params)
    with blas_threads(config.torch_threads):
        result = _CHILD_STAGES[stage](project, config, *args, log=lines.append)
    return time.perf_counter() - start, lines, result


def _simulate_all(
    project: Project, config: PipelineConfig, sims: list[tuple[str, str]], progress: _Progress
) -> int:
    """Run the simulation stages ``sims`` ((motion, ``"proxy"`` | ``"target"``), in order).

    Where there is a core for each, :data:`SIM_PROCESSES` at a time, each in a spawned process:
    each target once its motion's proxy has ended (it is embedded in, or follows, the proxy);
    the stage table keeps the order of ``sims``. Otherwise one after the other, with a progress
    bar each. Embedded targets read one binding to the proxy (:func:`stage_embedding`): the
    main process makes it while the first proxies simulate (first, with one process). Returns
    how many ran at once.
    """
    names = {sim: f"simulate {sim[0]} ({sim[1]})" for sim in sims}
    workers = min(SIM_PROCESSES, os.cpu_count() or 1, len(sims))
    bind = config.target_mode != "simulate" and any(which == "target" for _, which in sims)
    if workers < 2:
        if bind:
            progress.stage(EMBEDDING_STAGE, lambda: stage_embedding(project, config, progress.log))
        for (motion, which), name in names.items():
            bar = _sim_bar(name)
            try:
                progress.stage(
                    name,
                    lambda m=motion, w=which, b=bar: stage_simulate(
                        project, config, m, w, progress.log, b
                    ),
                )
            except InputError as exc:
                raise _clip_error(exc, motion, which) from None
        return 1
    progress.log(f"  simulating {workers} clips at a time, each in a process of its own")
    params = config.as_params()
    # Each target as soon as its proxy has ended, the proxies that have one first, then the
    # longest: the clips still running at the end are short, so the other process is not
    # left waiting for long.
    motions = [config.train_motion, *available_extra_motions(config)]
    motions += [*available_validation_motions(config), *available_test_motions(config)]
    frames = {m.name: m.frames for m in motions}
    embedded = {motion for motion, which in sims if which == "target"}
    queue = sorted(
        (sim for sim in sims if sim[1] == "proxy"),
        key=lambda sim: (sim[0] not in embedded, -frames.get(sim[0], 0)),
    )
    targets = [sim for sim in sims if sim[1] == "target"]
    ended: set[str] = set()
    running: dict = {}
    # each simulation's place in the costs (they end out of order): after the binding's
    first = progress.eta.done + int(bind)
    place = {sim: first + i for i, sim in enumerate(sims)}
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        while queue or targets or running:
            while len(running) < workers:
                ready = [t for t in targets if t[0] in ended or (t[0], "proxy") not in names]
                if not ready and not queue:
                    break
                job = ready[0] if ready else queue.pop(0)
                if ready:
                    targets.remove(job)
                future = pool.submit(_stage_worker, "simulate", str(project.root), params, *job)
                running[future] = job
            if bind:  # before any target can start: none does before its proxy has ended
                progress.stage(
                    EMBEDDING_STAGE, lambda: stage_embedding(project, config, progress.log)
                )
                bind = False
            for future in wait(running, return_when=FIRST_COMPLETED).done:
                motion, which = running.pop(future)
                try:
                    seconds, lines, _ = future.result()
                except InputError as exc:
                    raise _clip_error(exc, motion, which) from None
                for line in lines:
                    progress.log(line)
                progress.finished(
                    names[(motion, which)], seconds, seconds / workers, place[(motion, which)]
                )
                ended |= {motion} if which == "proxy" else set()
    finally:  # a failed simulation stops the run: the queued ones are dropped
        pool.shutdown(wait=True, cancel_futures=True)
    for name in names.values():  # the table in the order of the stages, not of their ends
        progress.stage_times[name] = progress.stage_times.pop(name)
    return workers


def _clip_error(exc: InputError, motion: str, which: str) -> InputError:
    """A simulation's refusal with the clip named, in the one line the user sees."""
    return InputError(f"{exc.problem} (clip {motion}, {which})", exc.path)


def _two_lanes(config: PipelineConfig) -> bool:
    """Whether a second process can run beside the main one: a core for each, each running
    ``torch_threads`` threads."""
    return (os.cpu_count() or 1) >= 2 * config.torch_threads


#: A stage for a second lane: (its key in :data:`_CHILD_STAGES`, its name in the stage table,
#: its own arguments after the project and the config).
Job = tuple[str, str, tuple[str, ...]]


def _lane_worker(root: str, params: dict, jobs: list[Job]) -> list[tuple[float, list[str], object]]:
    """Child-process entry: the ``jobs`` one after the other; each one's seconds, log lines and
    result."""
    return [_stage_worker(stage, root, params, *args) for stage, _, args in jobs]


class _Lane:
    """Stages that run one after the other beside the main process's (:func:`_beside`)."""

    def __init__(self, jobs: list[Job], progress: _Progress, future=None, pool=None, done=None):
        self.jobs, self.progress = jobs, progress
        self._future, self._pool, self._results = future, pool, done

    def wait(self) -> list[object]:
        """Wait for the lane (re-raising a stage's error), log its stages' lines, record their
        seconds under their names in the stage table; their results, in order."""
        if self._future is None:
            return self._results
        try:
            runs = self._future.result()
        finally:
            self._pool.shutdown()
        for (_, name, _), (seconds, lines, _) in zip(self.jobs, runs):
            for line in lines:
                self.progress.log(line)
            self.progress.finished(name, seconds, seconds / 2)
        return [result for _, _, result in runs]


def _beside(
    project: Project, config: PipelineConfig, jobs: list[Job], progress: _Progress
) -> _Lane:
    """Start ``jobs`` (stages of :data:`_CHILD_STAGES`, in order) in a spawned process, to run
    beside the main process's next stages, where there are two lanes (:func:`_two_lanes`; the
    work and its results are the same wherever it runs); else run them now, one after the
    other. The lane's :meth:`_Lane.wait` logs them and records their seconds."""
    if not _two_lanes(config):
        results = [
            progress.stage(
                name, lambda k=key, a=args: _CHILD_STAGES[k](project, config, *a, log=progress.log)
            )
            for key, name, args in jobs
        ]
        return _Lane(jobs, progress, done=results)
    pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
    future = pool.submit(_lane_worker, str(project.root), config.as_params(), jobs)
    for _, name, _ in jobs:
        progress.log(f"  {name}: in a second process, beside the stages that follow")
        progress.beside.append(name)
    return _Lane(jobs, progress, future, pool)


def run_demo(
    config: PipelineConfig, out: str | Path, *, preset_name: str = "custom", force: bool = False
) -> dict:
    """Run every stage into the project folder ``out``; write ``report.json`` and ``report.md``.

    The baselines train in a spawned process beside our renderer (2 cores or more), so a script
    that calls this must start from an ``if __name__ == "__main__":`` guard (Python's rule for
    the spawn start method; ``dng demo`` has one).
    """
    with blas_threads(config.torch_threads):  # the caller's own limits come back after
        return _run_demo(config, Path(out), preset_name, force)


def _run_demo(config: PipelineConfig, out: Path, preset_name: str, force: bool) -> dict:
    """:func:`run_demo`'s work."""
    project = Project(out)
    project.root.mkdir(parents=True, exist_ok=True)
    made_by = provenance()
    if force:
        for record in project.root.rglob(RECORD_NAME):
            record.unlink()
    made_by["from_empty"] = not any(project.root.rglob(RECORD_NAME))
    project.save_settings({"preset": preset_name, "pipeline": config.as_params()})
    tests = [m.name for m in available_test_motions(config)]
    train = config.train_motion.name
    sims = [(train, "proxy")] + ([(train, "target")] if config.simulate_target else [])
    sims += [(m.name, "proxy") for m in available_extra_motions(config)]
    sims += [(m.name, "proxy") for m in available_validation_motions(config)]
    sims += [(name, "proxy") for name in tests]
    validation = renderer_validation_motion(config) if config.simulate_target else None
    checked = [validation.name] if validation else []  # the renderers' validation motion
    if config.simulate_target:
        sims += [(name, "target") for name in [*checked, *tests]]
    progress = _Progress(stage_costs(config))
    log = progress.log
    if len(tests) < len(config.test_motions):
        log("note: real motion capture not found (install assimp-testmodels); skipping it")
    if config.simulate_target and config.renderer_validation and not checked:
        log(
            f"note: the validation motion {config.renderer_validation} is not on this machine "
            "(install assimp-testmodels): no protocol V, so no setting can be chosen here"
        )

    progress.stage("motions", lambda: stage_motions(project, config, log))
    progress.stage("garment", lambda: stage_garment(project, config, log))
    proxy_report = progress.stage("proxy", lambda: stage_proxy(project, config, log))
    sim_processes = _simulate_all(project, config, sims, progress)
    sim_reports = {
        f"{motion}-{which}": json.loads(
            project.path(f"sim/{motion}-{which}", "report.json").read_text()
        )
        for motion, which in sims
    }
    renderer = baselines = evaluation = videos = None
    if not config.simulate_target:
        j2c = progress.stage("joint2coarse", lambda: stage_joint2coarse(project, config, log))
    else:
        # Two lanes where there are two cores. Joint2Coarse needs only the proxies'
        # simulations, the training renders only the targets': side by side, every ray cast
        # on one thread (``raster_threads``: on every core they took half of Joint2Coarse's
        # speed). The evaluation's ground-truth sets are needed by it alone: those that fit
        # follow the training renders while Joint2Coarse trains, the rest the baselines in the
        # second lane, beside our renderer (both need Joint2Coarse's proxy and the training
        # renders).
        early, late = _share_sets(config)
        lane = _beside(project, config, [("joint2coarse", "joint2coarse", ())], progress)
        try:
            progress.stage(
                "dataset (ground-truth renders)", lambda: stage_dataset(project, config, log)
            )
            for (_, name, args), _ in early:
                progress.stage(name, lambda a=args: _testset(project, config, *a, log=log))
        finally:
            (j2c,) = lane.wait()
        named = ", ".join(config.baselines)
        first = [("baselines", f"baselines ({named})", ())] if config.baselines else []
        lane = _beside(project, config, first + [job for job, _ in late], progress)
        try:
            renderer = progress.stage(
                "neural renderer", lambda: stage_renderer(project, config, log)
            )
        finally:
            results = lane.wait()
        baselines = results[0] if config.baselines else {}
        for name in config.ablations:
            progress.stage(
                f"ablation {name}", lambda n=name: stage_ablation(project, config, n, log)
            )
        # The evaluation one motion at a time, shared between two lanes; the videos, which need
        # only our renderer and Joint2Coarse, start the second. Then the report that pools them.
        protocols = eval_motions(config)
        headers = {
            m: f"evaluation of {m} (protocol {p}, unseen cameras)" for m, p in protocols.items()
        }
        mine, theirs = _share_evaluation(config) if _two_lanes(config) else (list(protocols), [])
        second: list[Job] = [("videos", "videos (ground truth | neural render)", ())]
        lane = _beside(
            project, config, second + [("eval_motion", headers[m], (m,)) for m in theirs], progress
        )
        try:
            for motion in mine:
                progress.stage(
                    headers[motion], lambda m=motion: stage_eval_motion(project, config, m, log)
                )
        finally:
            videos = lane.wait()[0]
        evaluation = progress.stage(
            "evaluation (protocols V, U and P, unseen cameras)"
            if checked
            else "evaluation (protocols U and P, unseen cameras)",
            lambda: stage_eval(project, config, log),
        )

    report = {
        "preset": preset_name,
        "command": f"dng demo --preset {preset_name} --out {out}",
        "project": str(out),
        "provenance": made_by,
        "config": config.as_params(),
        "stage_seconds": progress.stage_times,
        "simulation_processes": sim_processes,
        "stages_beside": progress.beside,
        "proxy": proxy_report,
        "simulation": sim_reports,
        "joint2coarse": j2c,
        "renderer": renderer,
        "baselines": baselines,
        "evaluation": evaluation,
        "videos": videos,
        "against_the_paper": deviations_json(config),
        "total_seconds": time.perf_counter() - progress.start,
    }
    write_json(project.root / "report.json", report)
    with atomic_open(project.root / "report.md", "w", encoding="utf-8") as f:
        f.write(report_markdown(report))
    log(f"done in {report['total_seconds'] / 60:.1f} min: {project.root / 'report.md'}")
    return report


def joint2coarse_physics_markdown(j: dict) -> list[str]:
    """The unseen motions' physics beside the distance: penetration of the body's capsules and
    edge stretch, of the prediction, the prediction pushed out and the simulation, with the
    inference times (``-`` for a project made before a figure existed)."""
    lines = [
        "| unseen motion | penetration mean / max (mm) | penetrating vertices | with push-out | "
        "simulation | stretch p99 / max | with push-out | simulation | hem radius, mean (mm): "
        "prediction / simulation | its mean difference (mm) | batch inference (ms/frame) | "
        "streaming (ms/frame, median / p95) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]

    def stretch(d: dict | None) -> str:
        return f"{d['p99']:.3f} / {d['max']:.3f}" if d else "-"

    def hem(m: dict) -> tuple[str, str]:
        r, s = m.get("hem_radius_mm"), m.get("simulation_hem_radius_mm")
        if not r or not s:
            return "-", "-"
        diff = sum(abs(a - b) for a, b in zip(r, s)) / len(r)
        return f"{sum(r) / len(r):.0f} / {sum(s) / len(s):.0f}", f"{diff:.1f}"

    for name, m in j["motions"].items():
        p, q = m["penetration_mm"], m["with_push_out"]["penetration_mm"]
        s = m.get("simulation_penetration_mm")
        sim = f"{s['mean']:.2f} / {s['max']:.1f} ({s['fraction']:.1%})" if s else "-"
        lines.append(
            f"| `{name}` | {p['mean']:.2f} / {p['max']:.1f} | {p['fraction']:.1%} | "
            f"{q['mean']:.2f} / {q['max']:.1f} ({q['fraction']:.1%}) | {sim} | "
            f"{stretch(m.get('stretch'))} | {stretch(m['with_push_out'].get('stretch'))} | "
            f"{stretch(m.get('simulation_stretch'))} | {' | '.join(hem(m))} | "
            f"{m['batch_ms_per_frame']:.3f} | {_stream_ms(m)} |"
        )
    return lines


def joint2coarse_splits_markdown(j: dict) -> list[str]:
    """The splits, and every model's mean / p95 vertex error (mm) per validation and test
    motion, side by side (the project's model first, then ``compare``)."""
    splits = j.get("splits")
    if not splits:
        return []
    lines = [f"- {k}: " + ", ".join(f"`{n}`" for n in v) for k, v in splits.items()]
    models = {j.get("model", "paper"): j, **j.get("compare", {})}
    lines += ["", "| split | motion | " + " | ".join(f"{m} mean / p95 (mm)" for m in models) + " |"]
    lines.append("| --- | --- |" + " --- |" * len(models))
    for split, key in (("validation", "validation_motions"), ("test", "motions")):
        names = list(j.get(key, {}))
        sums = {m: [0.0, 0.0] for m in models}
        for name in names:
            cells = []
            for m, r in models.items():
                e = r[key][name]["error_mm"]
                sums[m][0] += e["mean_mm"] / len(names)
                sums[m][1] += e["p95_mm"] / len(names)
                cells.append(f"{e['mean_mm']:.1f} / {e['p95_mm']:.0f}")
            lines.append(f"| {split} | `{name}` | " + " | ".join(cells) + " |")
        if names:
            cells = [f"{a:.1f} / {b:.0f}" for a, b in sums.values()]
            lines.append(f"| {split} | **mean** | " + " | ".join(cells) + " |")
    return [*lines, ""]


def _stream_ms(m: dict) -> str:
    s = m.get("streaming_ms_per_frame")
    return f"{s['median']:.2f} / {s['p95']:.2f}" if s else "n/a"


def _fmt(summary: dict | None, digits: int = 4) -> str:
    if not summary or summary.get("mean") is None:
        return "n/a"
    return f"{summary['mean']:.{digits}f} ± {summary['std']:.{digits}f}"


def _schedule(cfg: dict, steps: int) -> str:
    """How a run's learning rates moved (``training.schedule``), from its config dict."""
    start = cfg.get("lr_decay_from", 1.0)  # reports from before the option: constant
    if start >= 1.0:
        return "constant"
    return f"falling linearly to zero from step {round(start * steps)}"


def metrics_table(methods: dict) -> list[str]:
    """One row per method: the garment region's MSE, then the measures that see its detail
    (GMSD, the spread of the gradient similarity's deficit, and its mean, both lower is better;
    the detail ratio, 1 is as much fine detail as the ground truth), its
    SSIM (only ours pastes the real background outside the garment), then full-frame MSE, PSNR,
    SSIM, flicker and the garment region's tOF (TecoGAN's optical-flow difference, pixels). A
    report made before a metric existed shows n/a."""
    lines = [
        "| method | MSE, garment | GMSD, garment | GMS deficit, garment | detail, garment | "
        "SSIM, garment | MSE | PSNR (dB) | SSIM | flicker | tOF, garment (px) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, m in methods.items():
        lines.append(
            f"| {name} | {_fmt(m['mse_masked'])} | {_fmt(m.get('gmsd_masked'), 3)} | "
            f"{_fmt(m.get('gms_masked'), 3)} | {_fmt(m.get('detail_masked'), 2)} | {_fmt(m['ssim_masked'])} | {_fmt(m['mse'])} | "
            f"{_fmt(m['psnr'], 2)} | {_fmt(m['ssim'])} | {_fmt(m['flicker'])} | "
            f"{_fmt(m.get('tof_masked'), 3)} |"
        )
    return lines


def ratio_sentence(methods: dict) -> str:
    """Ours over DNR's MSE, garment region first, on Joint2Coarse's and the simulated proxy."""
    r = ours_to_dnr(methods)
    parts = []
    for metric, what in (("mse_masked", "garment-region MSE"), ("mse", "full-frame MSE")):
        j2c, sim = (
            r.get(f"{metric}_ratio_ours_to_dnr"),
            r.get(f"{metric}_ratio_ours_to_dnr_simulated_proxy"),
        )
        if j2c is None:
            continue
        parts.append(
            f"{what} {j2c:.2f} on Joint2Coarse's proxy"
            + (
                f", {sim:.2f} on the simulated proxy (the renderers alone)"
                if sim is not None
                else ""
            )
        )
    return "Ours / DNR: " + "; ".join(parts) + "." if parts else ""


def _renderer_markdown(report: dict) -> list[str]:
    """The renderer's training and the comparison table (the paper's Table 1)."""
    r, ev = report.get("renderer"), report.get("evaluation")
    if not r:
        return []
    cfg = r["config"]
    lines = [
        "",
        "## Neural renderer",
        "",
        f"{r['steps']} steps at {cfg['image_size']} px on the {r['samples']} samples of `dataset/` "
        f"({r['seconds_per_step']:.2f} s/step; perceptual loss "
        f"{'on' if r['perceptual'] else 'off: no VGG19 weights file'}; "
        f"{r['skipped_steps']} steps skipped by the NaN guard). "
        f"Loss {cfg['w_l1']:g} L1"
        + (f" + {cfg['w_pyramid']:g} Laplacian pyramid" if cfg.get("w_pyramid") else "")
        + (f" + {cfg['w_detail']:g} detail energy" if cfg.get("w_detail") else "")
        + (f" + {cfg['w_perceptual']:g} perceptual" if r["perceptual"] else "")
        + f" + {cfg['w_fm']:g} feature matching + {cfg['w_gan']:g} GAN; "
        f"Adam {cfg['lr_g']:g} (network) and {cfg['lr_d']:g} (discriminator), "
        f"{_schedule(cfg, r['steps'])}. "
        f"L1 {r['first']['l1']:.4f} at step {r['first']['step']:.0f} -> {r['last']['l1']:.4f} "
        f"at step {r['last']['step']:.0f}.",
        "",
        "![loss](renderer/loss.png)",
    ]
    for kind, b in (report.get("baselines") or {}).items():
        lines.append(
            f"- baseline `{kind}`: {b['steps']} steps, {b['seconds_per_step']:.2f} s/step, "
            f"learning rates {_schedule(b['config'], b['steps'])}"
        )
    if not ev:
        return lines
    v = ev.get("validation")
    if v:
        lines += [
            "",
            "## Evaluation: the validation motion (protocol V)",
            "",
            f"`{v['motion']}`, one of Joint2Coarse's validation motions, from cameras of its own "
            f"(`testset/{v['motion']}/`, a camera stream no test set uses): every setting of our "
            "renderer and of the baselines is chosen on these figures; the test motions and the "
            "training motion's unseen cameras below are only reported. Same metrics as below.",
            "",
            *metrics_table(v["methods"]),
        ]
        ratios = ratio_sentence(v["methods"])
        lines += ["", ratios] if ratios else []
    lines += [
        "",
        "## Evaluation: unseen motions from unseen cameras (protocol U)",
        "",
        f"Test motions: {', '.join(f'`{m}`' for m in ev['test_motions'])}. Each sample renders "
        "frames t and t+1; MSE is the per-frame mean squared error of pixel values in [0, 1] "
        "(mean ± std over frames); masked metrics are on the garment region; flicker is "
        "mean |(R[t+1] - R[t]) - (I[t+1] - I[t])| (lower is steadier); tOF is the mean "
        "|F_R - F_I| of the two videos' optical flow from t to t+1 (OpenCV's Farneback, "
        "pixels; lower moves more as the ground truth does). Every method renders "
        "Joint2Coarse's proxy (no simulation at test time); the rows marked simulated proxy "
        "render the simulation's (the renderers alone).",
        "",
        *metrics_table(ev["methods"]),
    ]
    ratios = ratio_sentence(ev["methods"])
    if ratios:
        lines += [
            "",
            ratios + " The paper's Table 1: 0.57 (0.116 / 0.204, full frame).",
        ]
        if report.get("project"):
            lines += [
                "",
                "How each method's MSE, and this ratio, move with Joint2Coarse's error (every "
                "method rendering proxies between the simulated one and Joint2Coarse's): "
                f"`dng bench placement --project {report['project']}`.",
            ]
    ours, ours_sim = ev["methods"].get("ours"), ev["methods"].get("ours (simulated proxy)")
    if ours and ours_sim:
        share = 1.0 - ours_sim["mse"]["mean"] / ours["mse"]["mean"]
        lines += [
            "",
            f"{share:.0%} of our MSE on Joint2Coarse's proxy is gone on the simulated proxy: that "
            "part is where Joint2Coarse puts the garment on unseen motion, and every method shares "
            "it (the Joint2Coarse table above; its autoencoder rows show what the decoder reaches "
            "when given the simulated shapes themselves).",
        ]
    p = ev.get("protocol_p")
    if p:
        lines += [
            "",
            "## Evaluation: the training motion from unseen cameras (protocol P, the paper's)",
            "",
            f"`{p['motion']}`, the motion the renderer and Joint2Coarse trained on, from cameras "
            "the training never saw (`testset/" + p["motion"] + "/`): the paper's Table 1 "
            "protocol. Same metrics as above.",
            "",
            *metrics_table(p["methods"]),
        ]
        ratios = ratio_sentence(p["methods"])
        if ratios:
            lines += [
                "",
                ratios + " The paper's Table 1: 0.57 (0.116 / 0.204, full frame), against its "
                "simulated ground truth; this project's ground truth is named in its Ground truth "
                "section.",
            ]
    first = next(iter(ev["motions"].values()), {})
    lines += _weights_metrics_markdown(ev["motions"], next(iter(first.values()), {}))
    lines += ["", "Ground truth (top row) and every method on the same frames:", ""]
    shown = [*([v["motion"]] if v else []), *ev["motions"], *([p["motion"]] if p else [])]
    lines += [f"![{m}](eval/{m}/compare.png)" for m in shown]
    videos = report.get("videos") or {}
    if videos:
        lines += ["", "Videos of the unseen motions (simulation | neural render, the camera circles "
                  "the body):", ""]  # fmt: skip
        for name, v in videos.items():
            ms = v["median_ms"]
            lines.append(
                f"- [`videos/{name}.gif`](videos/{name}.gif): {v['frames']} frames; neural path "
                f"{ms['total']:.0f} ms/frame median (Joint2Coarse {ms['joint2coarse']:.2f}, body "
                f"background {ms['background']:.0f}, raster + network {ms['raster+network']:.0f})"
            )
    return lines


def _weights_metrics_markdown(motions: dict, first: dict) -> list[str]:
    """FID, video FID and tLP (tLP lower is better: how far the render's change from frame to
    frame is from the ground truth's, perceptually) per unseen motion and method, or each one's
    "unavailable" line where no weights file was given (a report made before tLP existed: no
    tLP line)."""
    lines = []
    columns = [
        (key, label)
        for key, label in (("fid", "FID"), ("video_fid", "video FID"), ("tlp", "tLP"))
        if key in first
    ]
    missing = [(k, label) for k, label in columns if first[k].get("value") is None]
    for key, label in missing:
        lines += ["", f"{label}: {first[key].get('status', 'unavailable')}."]
    shown = [c for c in columns if c not in missing]
    if shown:
        lines += [
            "",
            "| motion | method | " + " | ".join(label for _, label in shown) + " |",
            "| --- | --- |" + " --- |" * len(shown),
        ]
        for motion, methods in motions.items():
            for name, m in methods.items():
                cells = " | ".join(f"{m[k]['value']:.3f}" for k, _ in shown)
                lines.append(f"| {motion} | {name} | {cells} |")
    return lines


def _hem_end_cell(sim: dict) -> str:
    """The simulation table's "hem at end" cell of one clip's report: the figure, or n/a with
    what ruled it out (the body not standing over the clip's last half second)."""
    if sim.get("hem_rise_end_mm") is not None:
        return f"{sim['hem_rise_end_mm']:.0f}"
    end = [sim.get(k) for k in ("end_tilt_deg", "end_hips_height", "end_feet_m")]
    return "n/a" if None in end else f"n/a ({not_standing(*end)})"


def _ground_truth_markdown(report: dict) -> list[str]:
    """The detailed target per clip: how it moves (simulated or embedded in the proxy), its
    edge stretch and compression (``len / rest - 1``), tears, and its contact sheet."""
    targets = {k: v for k, v in report["simulation"].items() if k.endswith("-target")}
    if not targets:
        return []
    lines = ["", "## Ground truth: the detailed target", ""]
    proxies = [v for k, v in report["simulation"].items() if k.endswith("-proxy")]
    layered = [n for v in proxies[:1] for n in v.get("notes", []) if "layers beneath" in n]
    if layered:
        lines += [f"The proxy it is embedded in is simulated {layered[0]}.", ""]
    lines += [
        "| clip | mode | stretch max / p99 | compression max / p99 | torn edges (stretch > 1) |",
        "| --- | --- | --- | --- | --- |",
    ]
    modes = {"embed": "embedded in the proxy", "tiers": "embedded, tiers simulated on it"}
    for name, s in targets.items():
        mode = modes.get(s.get("mode"), "simulated")
        if s.get("contact"):
            mode += f", kept {1e3 * s['contact']['margin']:.0f} mm out of the body"
        p99 = s.get("strain_p99")
        cp99 = s.get("compression_p99")
        lines.append(
            f"| {name[: -len('-target')]} | {mode} | {s['strain_max']:.3f} / "
            f"{'-' if p99 is None else f'{p99:.3f}'} | {s.get('compression_max', 0.0):.3f} / "
            f"{'-' if cp99 is None else f'{cp99:.3f}'} | {s.get('torn_edges', '-')} |"
        )
    lines += _own_dynamics_markdown(targets)
    for name, s in targets.items():
        if s.get("sheet"):
            rows = "proxy, embedded target, target" if s.get("mode") == "tiers" else "proxy, target"
            lines += ["", f"{name[: -len('-target')]}: {rows} (rows, top to bottom)", ""]
            lines.append(f"![{name}](sim/{name}/{s['sheet']})")
    return lines


def _own_dynamics_markdown(targets: dict) -> list[str]:
    """Per clip with simulated tiers: how far the target moves from the same target embedded in
    the same proxy (its dynamics of its own), over the garment and the tiers, beside the tiers'
    floor (a 10 um nudge's distance, over the clip's first frames, and the own dynamics over
    the same frames), their speed and their crossings of the layer beneath."""
    tiered = {k: v for k, v in targets.items() if v.get("own_dynamics")}
    if not tiered:
        return []
    lines = [
        "",
        "Dynamics of its own: the distance (mm, mean / p95 over frames and vertices) of the "
        "target from the same target embedded in the same simulated proxy; the floor is the "
        "distance between two runs of the tiers 10 um apart, over the clip's first frames, "
        "beside the own dynamics over the same frames. Crossings: (frame, vertex) pairs of the "
        "tiers behind the layer beneath them.",
        "",
        "| clip | garment | tiers | tiers, first frames | floor (tiers) | frames | crossings "
        "(deepest) | tiers' ms/frame |",
        "| --- | --- | --- | --- | --- | ---: | --- | ---: |",
    ]

    def pair(d: dict | None) -> str:
        return "-" if not d else f"{d['mean_mm']:.1f} / {d['p95_mm']:.1f}"

    for name, s in tiered.items():
        own, floor, t = s["own_dynamics"], s.get("floor") or {}, s["tiers"]
        lines.append(
            f"| {name[: -len('-target')]} | {pair(own['garment'])} | {pair(own['tiers'])} | "
            f"{pair(floor.get('own_dynamics_tiers'))} | {pair(floor.get('tiers'))} | "
            f"{floor.get('frames', '-')} | {100 * t['layer_crossing_fraction']:.2f} % "
            f"({t['layer_crossing_max_mm']:.1f} mm) | {t['ms_per_frame']:.0f} |"
        )
    return lines


def _against_the_paper_markdown(report: dict) -> list[str]:
    """What each method of the comparison got, and every deviation from the paper."""
    if "against_the_paper" not in report:
        return []
    rows, methods = from_json(report["against_the_paper"])
    lines = []
    if report.get("renderer"):
        lines += [
            "",
            "## What each method got",
            "",
            "Trainable parameters of what renders (no discriminator), counted on a fresh model "
            "of this project's configuration.",
            "",
            methods_markdown(methods),
        ]
    lines += ["", "## Deviations from the paper", "", deviations_markdown(rows)]
    return lines


#: How the report names each proxy solver (``PipelineConfig.sim_solver``).
_SOLVER_NAMES = {"style3d": "newton's Style3D", "implicit": "our implicit solver"}


def report_markdown(report: dict) -> str:
    """The human-readable report: every figure with the command that produced it."""
    cmd = f"`{report['command']}`"
    cfg = report["config"]
    lines = [
        f"# Garment studio demo ({report['preset']} preset)",
        "",
        f"Every figure here was measured by {cmd}; the numbers are in `report.json` beside this.",
        "",
        "## Stages",
        "",
        "| stage | seconds (0 = reused) |",
        "| --- | --- |",
    ]
    lines += [f"| {k} | {v:.1f} |" for k, v in report["stage_seconds"].items()]
    if report.get("simulation_processes", 1) > 1:
        lines += [
            "",
            f"The simulations ran {report['simulation_processes']} at a time, each in a process "
            "of its own: their seconds overlap (the total below is the run's own).",
        ]
    if report.get("stages_beside"):
        named = " and ".join(f"`{n}`" for n in report["stages_beside"])
        lines += [
            "",
            f"{named} ran in a second process beside the main one's stages: their seconds "
            "overlap those stages'.",
        ]
    p = report["proxy"]
    counts = p.get("proxy", {})
    dist = p.get("distance", {})
    lines += [
        "",
        f"## Proxy of `{cfg['garment']}`",
        "",
        "```",
        json.dumps({"proxy": counts, "distance": dist}, indent=1)[:1500],
        "```",
        "",
        f"## Simulation ({_SOLVER_NAMES.get(cfg.get('sim_solver'), 'newton')}, CPU)",
        "",
        "Hem ratio: the hem's mean distance from the waist's axis over the clip's second half "
        "over the garment's as dressed (above 1: it flared out, below 1: it closed in; n/a "
        "for an embedded target, or a simulation made before the figure existed). Waistband "
        "drift: the pinned waistband's largest rise or sink along the pelvis (hips joint to "
        "Spine1) against frame 0. Hem at end: the hem's height along the pelvis over the "
        "clip's last half second against the garment's as dressed (a skirt that rode up and "
        "stayed; one hanging settled reads a little below 0), only where the body stands "
        "all that while: else n/a with the pelvis's tilt, the hips' height (a share of "
        "standing's) or the feet's stance that ruled it out. Both relative to the hips joint, n/a as for the hem "
        "ratio.",
        "",
        "| clip | frames | vertices | ms/frame | penetration mean / max (mm) | max strain | "
        "hem ratio | waistband drift (mm) | hem at end (mm) | finite |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]

    def figure(value, spec: str) -> str:
        return "n/a" if value is None else format(value, spec)

    for name, s in report["simulation"].items():
        lines.append(
            f"| {name} | {s['frames']} | {s['vertices']} | {s['ms_per_frame']:.0f} | "
            f"{s['penetration_mean_mm']:.2f} / {s['penetration_max_mm']:.1f} | "
            f"{s['strain_max']:.3f} | {figure(s.get('hem_radius_ratio'), '.2f')} | "
            f"{figure(s.get('waistband_rise_max_mm'), '.0f')} | "
            f"{_hem_end_cell(s)} | {s['finite']} |"
        )
    lines += _ground_truth_markdown(report)
    j = report["joint2coarse"]
    lines += [
        "",
        "## Joint2Coarse: proxy from joints, against simulation",
        "",
        f"Model: `{j.get('model', 'paper')}`. Trained on `{j['train_motion']}`"
        + "".join(f" and `{m}`" for m in j.get("extra_train_motions", []))
        + "; held-out frames (validation) and unseen motions."
        + _mirror_markdown(j.get("mirror")),
        "",
        *joint2coarse_splits_markdown(j),
        "| data | mean (mm) | p95 (mm) | max (mm) |",
        "| --- | --- | --- | --- |",
    ]
    base = j.get("validation_mean_shape_baseline_mm")
    if base:
        lines.append(
            f"| validation, mean-shape baseline | {base['mean_mm']:.1f} | {base['p95_mm']:.1f} "
            f"| {base['max_mm']:.1f} |"
        )
    for stage, e in j["validation_error_mm"].items():
        lines.append(
            f"| validation after {stage} | {e['mean_mm']:.1f} | {e['p95_mm']:.1f} | "
            f"{e['max_mm']:.1f} |"
        )
    reach = ", the shape autoencoder on its simulated shapes (what the decoder reaches)"
    for name, m in j["motions"].items():
        rows = [("", m["error_mm"]), (", pushed out of the body", m["with_push_out"]["error_mm"])]
        if "autoencoder_error_mm" in m:
            rows.append((reach, m["autoencoder_error_mm"]))
        for label, e in rows:
            lines.append(
                f"| unseen `{name}` ({m['frames']} frames){label} | {e['mean_mm']:.1f} | "
                f"{e['p95_mm']:.1f} | {e['max_mm']:.1f} |"
            )
    lines += ["", *joint2coarse_physics_markdown(j)]
    lines += ["", "Side by side (simulation above, prediction below):", ""]
    lines += [f"![{name}](joint2coarse/compare-{name}.png)" for name in j["motions"]]
    lines += _renderer_markdown(report)
    lines += _against_the_paper_markdown(report)
    lines += [
        "",
        f"Total: {report['total_seconds'] / 60:.1f} min. Configuration: `report.json` (`config`).",
        "",
    ]
    return "\n".join(lines)
