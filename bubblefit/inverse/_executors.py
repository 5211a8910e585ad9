"""Executors of a sequence fit: the work of one chunk, in this process or on Dask.

One chunk is one task: its frames are fitted in order, each warm-started from the last
successful frame before it, its thickness carried on from the two last (:func:`fit_chunk`,
:func:`~bubblefit.inverse._parameters.extrapolated`). :class:`LocalExecutor` runs the
tasks in this process, one after the other; :class:`DaskExecutor` runs them on a
``distributed`` cluster: a local one (one single-threaded worker process per core, so two
workers do not fight over the same cores) or an existing one. A worker process keeps JAX's compiled
functions between tasks and shares the client's persistent compilation cache
(:func:`bubblefit.io.jaxcache.jax_setup`), so only its first frame pays the compilation.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import math
import os
import time
from dataclasses import dataclass, replace
from types import SimpleNamespace
from typing import Any

from ..errors import InputError
from ..io.jaxcache import jax_setup
from ._parameters import extrapolated
from ._plan import FrameRef, load_frame
from .fit import explained, fit_batch, fit_photo
from ._records import base_record, one_line, result_record, warm_init

__all__ = ["DEFAULT_FIT", "ChunkTask", "fit_chunk", "kept_model", "LocalExecutor", "DaskExecutor", "local_env",
           "SchedulerAddress", "read_security", "local_cluster", "start_client"]

DEFAULT_FIT = "bubblefit.inverse.fit:fit_photo"


_WORKER_READY = False

def _worker_setup(jax_settings: dict) -> None:
    """Once per process: the client's JAX settings (compilation cache, float64), through
    :func:`bubblefit.io.jaxcache.jax_setup`."""
    global _WORKER_READY
    if _WORKER_READY:
        return
    jax_setup(jax_settings.get("cache_dir"), enable_x64=jax_settings.get("enable_x64"))
    _WORKER_READY = True


def _read_frame(ref: FrameRef, base: dict, t0: float):
    """``(photo, None)``, or ``(None, failed record)`` for a frame that cannot be read."""
    try:
        return load_frame(ref), None
    except Exception as exc:  # unreadable frame: record and go on
        return None, dict(base, status="failed", converged=False, warm_start=False,
                          message=f"cannot read frame: {one_line(exc)}", fit_time_s=time.perf_counter() - t0)


def _fit_one(ref: FrameRef, env, options, init, background, scene, fit_fn) -> dict:
    """Fit one frame; a failure becomes a record with its reason, never an exception."""
    t0 = time.perf_counter()
    base = base_record(ref, init)
    photo, failed = _read_frame(ref, base, t0)
    if failed:
        return failed
    try:
        res = fit_fn(photo, env, options=options, background=background, init=init, scene=scene)
    except Exception as exc:  # a fit that raises fails this frame only
        return dict(base, status="failed", converged=False, message=f"fit failed: {one_line(exc)}",
                    fit_time_s=time.perf_counter() - t0)
    return result_record(base, res, time.perf_counter() - t0)


def kept_model(options, last: dict | None) -> str | None:
    """The model a warm-started frame keeps under ``model = "auto"``: the one the previous
    frame's fit kept, when that model explained its photo (converged, the reduced chi^2
    with the model-error floor within ``judge.ok_chi2``: :func:`bubblefit.inverse.fit.explained`,
    the rule by which ``auto`` keeps its first model). The light, exposure, roughness,
    reflectances and the film's optics do not change between the frames of one film, only
    its thickness, so neither does the model that explains them; None (``auto`` compares
    the models again) for another ``model``, or a previous frame that was not explained."""
    if getattr(options, "model", None) != "auto" or not last or last.get("status") != "ok":
        return None
    model = last.get("model")
    if model not in ("paper", "physical"):
        return None
    said = SimpleNamespace(converged=bool(last.get("converged")), chi2_floor=float(last.get("chi2_floor", math.inf)))
    return model if explained(said, options.judge) else None


def _unexplained(rec: dict, options) -> str | None:
    """Why a frame fitted with a kept model does not pass (None: it does): failed, not
    converged, or not explained within the floor (:func:`bubblefit.inverse.fit.explained`)."""
    if rec.get("status") != "ok":
        return rec.get("message") or "the fit failed"
    said = SimpleNamespace(converged=bool(rec.get("converged")), chi2_floor=float(rec.get("chi2_floor", math.inf)))
    if explained(said, options.judge):
        return None
    if not said.converged:
        return "it did not converge"
    return f"reduced chi^2 with the floor {said.chi2_floor:.3g} > {float(options.judge.ok_chi2):g}"


def _fit_warm(ref: FrameRef, env, options, init, last, background, scene, fit_fn) -> dict:
    """Fit a warm-started frame with the model the previous frame kept (:func:`kept_model`);
    when that fit does not explain the frame (:func:`_unexplained`), the frame falls back to the full fit under
    ``auto`` (both models compared), and its record says so
    (``fallback``)."""
    model = kept_model(options, last)
    if model is None:
        return _fit_one(ref, env, options, init, background, scene, fit_fn)
    rec = _fit_one(ref, env, replace(options, model=model), init, background, scene, fit_fn)
    why = _unexplained(rec, options)
    if why is None:
        return dict(rec, model_kept=model)
    full = _fit_one(ref, env, options, init, background, scene, fit_fn)
    full["fallback"] = (f"the {model} model kept from the previous frame did not explain this frame ({why}); "
                        "refitted under auto")
    full["fit_time_s"] = float(full.get("fit_time_s", 0.0)) + float(rec.get("fit_time_s", 0.0))
    return full


def _fit_batch(refs: list[FrameRef], env, options, init, previous, background, scene) -> list[dict]:
    """Fit consecutive frames together (:func:`bubblefit.inverse.fit.fit_batch`); one record each.
    If the batched fit raises, the frames are fitted one by one instead."""
    t0 = time.perf_counter()
    bases = [base_record(r, init) for r in refs]
    read = [_read_frame(r, b, t0) for r, b in zip(refs, bases)]
    good = [k for k, (photo, _) in enumerate(read) if photo is not None]
    recs = [failed for _, failed in read]
    try:
        results = fit_batch([read[k][0] for k in good], env, options=options, background=background, init=init,
                            previous=previous, scene=scene)
    except Exception:  # fall back to single fits, which record their own failures
        return [recs[k] or _fit_one(refs[k], env, options, init, background, scene, fit_photo)
                for k in range(len(refs))]
    share = (time.perf_counter() - t0) / max(len(good), 1)
    for k, res in zip(good, results):
        recs[k] = dict(result_record(bases[k], res, share), batch=len(good))
    return recs


def fit_chunk(todo: list[tuple[FrameRef, dict | None]], env, options, background, scene, jax_settings: dict,
              want_maps: bool, fit_function: str = DEFAULT_FIT, warm_start: bool = True,
              init: dict | None = None, batch: int = 1) -> list[dict]:
    """Fit the pending frames of one chunk, in order, each warm-started from the last success,
    its thicknesses extrapolated linearly from the two last
    (:func:`~bubblefit.inverse._parameters.extrapolated`), with the model that success kept
    (:func:`kept_model`, :func:`_fit_warm`); each frame's thickness map is built coarse to
    fine, as a single photo's (a map started from the predecessor's passed its order hops
    on to the next frames).

    Parameters
    ----------
    todo
        the chunk's frames in order, each with its finished record (None: to fit).
        Finished frames are not refitted; they only pass their result on as a warm start.
    env
        the environment map (:class:`~bubblefit.lighting.envmap.EnvMap`).
    options
        :class:`bubblefit.inverse.fit.FitOptions`.
    background, scene
        passed on to :func:`bubblefit.inverse.fit.fit_photo`.
    jax_settings
        the client's JAX settings (compilation cache, float64).
    want_maps
        keep each frame's thickness map (else it is dropped here, in the worker).
    fit_function
        ``"module:name"`` of the fit, called like :func:`bubblefit.inverse.fit.fit_photo`.
    warm_start
        False: every frame runs the global search (independent frames).
    init
        warm start of the chunk's first frame (the previous chunk's last result), or None.
    batch
        once two frames have warm-started results, fit up to this many following
        frames together (:func:`bubblefit.inverse.fit.fit_batch`, default fit function only).

    Returns
    -------
    list of dict
        One record per frame fitted, in order.
    """
    _worker_setup(jax_settings)
    fit_fn = _resolve(fit_function)
    batched = batch > 1 and warm_start and fit_function == DEFAULT_FIT

    out = []
    warm, prev, last = init, None, None

    def keep(rec):
        nonlocal warm, prev, last
        nxt = warm_init(rec)
        if nxt is not None:
            prev, warm, last = warm, nxt, rec

    i = 0
    while i < len(todo):
        ref, done = todo[i]
        if done is not None:
            keep(done)
            i += 1
            continue
        group = []
        if batched and warm is not None and prev is not None:
            while i + len(group) < len(todo) and len(group) < batch and todo[i + len(group)][1] is None:
                group.append(todo[i + len(group)][0])
        if len(group) >= 2:
            recs = _fit_batch(group, env, options, warm, prev, background, scene)
        elif warm_start and warm is not None:
            recs = [_fit_warm(ref, env, options, extrapolated(warm, prev), last, background, scene, fit_fn)]
        else:
            recs = [_fit_one(ref, env, options, None, background, scene, fit_fn)]
        for rec in recs:
            keep(rec)
            if not want_maps:
                rec.pop("_thickness_map", None)
            out.append(rec)
        i += len(recs)
    return out


def _resolve(target: str):
    """The function named ``"module:name"`` (importable on every worker)."""
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name or "fit_photo")


class _Lazy:
    """A call run when its ``result()`` is asked for (the in-process stand-in for a future)."""

    def __init__(self, fn, *args):
        self.fn, self.args, self._done = fn, args, False

    def result(self):
        if not self._done:
            self.value, self._done = self.fn(*self.args), True
        return self.value

    def done(self) -> bool:
        return True  # nothing to cancel

    def cancel(self):
        pass


def local_env() -> dict:
    """Environment of local worker processes: one thread each for XLA and BLAS."""
    flags = os.environ.get("XLA_FLAGS", "")
    extra = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    return {
        "XLA_FLAGS": f"{flags} {extra}".strip(),
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "XLA_PYTHON_CLIENT_PREALLOCATE": "false",
    }


class SchedulerAddress(str):
    """A Dask scheduler's address (``tcp://host:8786`` or ``tls://host:8786``) with the
    file of TLS credentials to reach it (``security_file``, see :func:`read_security`)."""

    security_file: str | None = None

    def __new__(cls, address: str, security_file: str | None = None):
        self = super().__new__(cls, address)
        self.security_file = security_file
        return self


#: Largest security file read (it names three files; a larger one is not one).
MAX_SECURITY_BYTES = 64 * 1024


def read_security(path: str):
    """``distributed.Security`` from a TOML file naming the TLS files of a cluster:
    ``tls_ca_file`` (the certificate authority), ``tls_client_cert`` and optionally
    ``tls_client_key`` (the client's certificate and key), as Dask's own configuration names
    them; relative paths are taken from the file's folder. Encryption is required."""
    import tomllib

    from distributed import Security

    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_SECURITY_BYTES + 1)
        if len(data) > MAX_SECURITY_BYTES:
            raise InputError(f"security file {path} is larger than {MAX_SECURITY_BYTES} bytes: not a security file")
        table = tomllib.loads(data.decode("utf-8"))
    except OSError as exc:
        raise InputError(f"cannot read security file {path}: {(exc.strerror or str(exc)).lower()}") from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"security file {path} is not TOML: {one_line(exc)}") from None
    names = ("tls_ca_file", "tls_client_cert", "tls_client_key")
    unknown = sorted(set(table) - set(names))
    if unknown or not table.get("tls_ca_file") or not table.get("tls_client_cert"):
        raise InputError(f"security file {path} must set tls_ca_file and tls_client_cert (and may set "
                         f"tls_client_key){'; unknown: ' + ', '.join(unknown) if unknown else ''}")
    folder = os.path.dirname(os.path.abspath(path))
    files = {}
    for name in names:
        if name in table:
            file = os.path.join(folder, os.path.expanduser(str(table[name])))
            if not os.path.isfile(file):
                raise InputError(f"security file {path}: {name} {table[name]!r} is not a file")
            files[name] = file
    return Security(require_encryption=True, **files)


#: The warning filter of the resource tracker a local cluster starts (``-W``): the reports
#: of its module, which are its notes on cleaning up after a process that ended without
#: releasing its semaphores.
TRACKER_FILTER = "ignore::UserWarning:multiprocessing.resource_tracker"


def quiet_resource_tracker() -> bool:
    """Start Python's ``multiprocessing`` resource tracker now, with :data:`TRACKER_FILTER`.

    A local Dask cluster's nannies hold two ``multiprocessing`` queues per worker process
    (three named semaphores each), which the resource tracker, a process of its own, is
    told about. When this process ends without closing them, killed with SIGKILL (the
    only end that skips :func:`close_local_cluster`), the tracker unlinks them and prints
    "resource_tracker: There appear to be 12 leaked semaphore objects to clean up at
    shutdown" (two workers): a note on its own cleanup, not an error of the command, which
    has already been reported (or not) by this process. The tracker is started with its
    module's warnings ignored, so it still cleans up, silently; the command's own errors
    are untouched. Returns False where the tracker was already running (started by
    something else, with this process's flags) or this Python lays it out otherwise."""
    try:
        from multiprocessing import resource_tracker, util

        tracker = resource_tracker._resource_tracker
        if getattr(tracker, "_fd", None) is not None:
            return False
        flags = util._args_from_interpreter_flags
    except (ImportError, AttributeError):  # pragma: no cover - another Python's layout
        return False
    util._args_from_interpreter_flags = lambda: [*flags(), "-W", TRACKER_FILTER]
    try:
        tracker.ensure_running()
    finally:
        util._args_from_interpreter_flags = flags
    return True


def local_cluster(n: int):
    """A local cluster of ``n`` single-threaded worker processes that only this process can
    use: every connection is TLS with a certificate made for this run
    (``distributed.Security.temporary``, held in memory), scheduler and workers listen on
    127.0.0.1 only, and the dashboard is off (Dask's HTTP routes stay on 127.0.0.1)."""
    from distributed import Client, LocalCluster, Security

    quiet_resource_tracker()
    security = Security.temporary()
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, protocol="tls://",
                           host="127.0.0.1", dashboard_address=None, security=security,
                           env=local_env(), silence_logs=40)
    try:
        return Client(cluster, security=security), cluster
    except BaseException:
        cluster.close()
        raise


def start_client(scheduler, workers: int | None):
    """(client, cluster or None, worker addresses to use) for a scheduler spec."""
    try:  # imported here: Dask costs a second of start-up that in-process runs do not need
        from distributed import Client
    except ImportError:  # pragma: no cover - dask is a dependency
        raise InputError("Dask is not installed: pip install 'dask[distributed]' (or use --workers 0)") from None
    cluster = None
    if scheduler is None:
        client, cluster = local_cluster(workers or os.cpu_count() or 1)
    elif isinstance(scheduler, str):
        file = getattr(scheduler, "security_file", None)
        if file is not None and not scheduler.startswith("tls://"):
            raise InputError(f"--scheduler-security needs a tls:// scheduler address, got {scheduler}")
        security = read_security(file) if file is not None else None
        try:
            client = Client(str(scheduler), timeout=30, security=security)
        except (OSError, TimeoutError, TypeError) as exc:
            hint = " (a tls:// scheduler needs --scheduler-security FILE)" if \
                scheduler.startswith("tls://") and file is None else ""
            raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {one_line(exc)}{hint}") from None
    else:
        client = scheduler  # an existing distributed.Client
    addrs = sorted(client.scheduler_info(n_workers=-1)["workers"]) if _takes_n_workers(client) else \
        sorted(client.scheduler_info()["workers"])
    if not addrs:
        client.wait_for_workers(1, timeout=60)
        addrs = sorted(client.scheduler_info()["workers"])
    if scheduler is not None and workers:
        addrs = addrs[:workers]
    return client, cluster, addrs


def _takes_n_workers(client) -> bool:
    try:
        return "n_workers" in inspect.signature(client.scheduler_info).parameters
    except (TypeError, ValueError):
        return False


@dataclass(frozen=True)
class ChunkTask:
    """What every chunk of one run shares: the data and settings :func:`fit_chunk` takes."""

    env: Any
    options: Any
    background: Any
    scene: Any
    jax_settings: dict
    want_maps: bool
    fit_function: str
    warm_start: bool
    batch: int


class LocalExecutor:
    """Runs chunks in this process, one after the other, as their results are asked for.
    An exception in a chunk is raised (there is no worker to lose)."""

    workers = 0

    def __init__(self, task: ChunkTask):
        self.task = task

    def submit(self, todo, init: dict | None = None) -> _Lazy:
        t = self.task
        return _Lazy(fit_chunk, todo, t.env, t.options, t.background, t.scene, t.jax_settings, t.want_maps,
                     t.fit_function, t.warm_start, init, t.batch)

    def completed(self, futures):
        """The futures in submission order (each runs when its result is read)."""
        return list(futures)

    def close(self) -> None:
        pass


class DaskExecutor:
    """Runs chunks as tasks of a ``distributed`` cluster: a local one (``scheduler=None``:
    ``workers`` single-threaded processes, one per core by default), the scheduler at an
    address, or a given ``distributed.Client``. The environment map and background are
    sent once to every worker; a task that fails (a lost worker) fails its chunk only."""

    def __init__(self, task: ChunkTask, scheduler=None, workers: int | None = None):
        self.task = task
        self.scheduler = scheduler
        self.client, self.cluster, self.addrs = start_client(scheduler, workers)
        self.workers = len(self.addrs)
        self.submitted = []
        try:
            self.env = self.client.scatter(task.env, broadcast=True, workers=self.addrs, hash=False)
            self.background = None if task.background is None else \
                self.client.scatter(task.background, broadcast=True, workers=self.addrs, hash=False)
        except BaseException:
            self.close()
            raise
        self.token = hashlib.sha1(f"{time.time()}{os.getpid()}{id(self)}".encode()).hexdigest()[:10]

    def submit(self, todo, init: dict | None = None):
        t = self.task
        key = f"bubblefit-chunk-{todo[0][0].index}-{len(self.submitted)}-{self.token}"
        f = self.client.submit(fit_chunk, todo, self.env, t.options, self.background, t.scene, t.jax_settings,
                               t.want_maps, t.fit_function, t.warm_start, init, t.batch, key=key,
                               workers=self.addrs, allow_other_workers=False, pure=False)
        self.submitted.append(f)
        return f

    def completed(self, futures):
        """The futures as they finish."""
        from distributed import as_completed

        return as_completed(list(futures))

    def close(self) -> None:
        """Cancel what is still pending; close the client and cluster this executor started
        (a local one through :func:`close_local_cluster`)."""
        for f in self.submitted:
            if not f.done():
                f.cancel()
        if self.cluster is not None:
            close_local_cluster(self.client, self.cluster)
        elif isinstance(self.scheduler, str) and self.client is not None:
            self.client.close()


#: Seconds a local cluster's workers are given to stop before they are ended.
CLOSE_TIMEOUT_S = 60.0

#: Loggers whose records during a local cluster's shutdown are the shutdown's own (a worker
#: that stopped while the scheduler was talking to it, a close that timed out).
_SHUTDOWN_LOGGERS = ("distributed", "tornado.application", "asyncio")


def close_local_cluster(client, cluster, timeout: float = CLOSE_TIMEOUT_S) -> None:
    """Close a local cluster this process started, quietly and always.

    The frames' results are on disk before the cluster is closed, so its shutdown cannot
    change them: the client closes, then the cluster within ``timeout`` seconds. Dask's
    shutdown chatter (connection resets, a timed-out worker close logged by tornado with a
    traceback) is not shown; a close that times out is one warning line, and the worker
    processes still alive are ended (SIGTERM, then SIGKILL), each through its
    ``multiprocessing`` handle, so that their queues' semaphores are released by their own
    finalisers rather than reported as leaked by Python's resource tracker at exit.
    """
    import logging
    import warnings

    # the handles are taken first: a close that times out may already have dropped its
    # nannies from ``cluster.workers`` while their processes still run
    procs = _worker_processes(cluster)
    saved = {name: logging.getLogger(name).level for name in _SHUTDOWN_LOGGERS}
    for name in _SHUTDOWN_LOGGERS:
        logging.getLogger(name).setLevel(logging.CRITICAL)
    try:
        try:
            client.close(timeout=timeout)
        except Exception:  # noqa: BLE001 - a client of a cluster going away
            pass
        try:
            cluster.close(timeout=timeout)
        except Exception as exc:  # noqa: BLE001 - TimeoutError, OSError, CommClosedError
            ended = _end_processes(procs)
            warnings.warn(f"the local Dask cluster did not stop within {timeout:g} s ({type(exc).__name__}); "
                          f"ended its {ended} worker process(es)", UserWarning,
                          stacklevel=2)
    finally:
        for name, level in saved.items():
            logging.getLogger(name).setLevel(level)


def _worker_processes(cluster) -> list:
    """The ``multiprocessing.Process`` handles of a local cluster's worker processes, held by
    each nanny."""
    procs = []
    for nanny in list(getattr(cluster, "workers", {}).values()):
        worker_process = getattr(nanny, "process", None)
        async_process = getattr(worker_process, "process", None)
        proc = getattr(async_process, "_process", None)
        if proc is not None:
            procs.append(proc)
    return procs


def _end_processes(procs: list) -> int:
    """End those of ``procs`` still running (SIGTERM, then SIGKILL); returns how many.

    A process has ended when its ``sentinel`` is ready (the pipe its end closes).
    ``is_alive`` is not asked: the nanny's watcher thread reaps the same child with its own
    ``join``, and a ``waitpid`` that loses that race reads as still alive."""
    from multiprocessing.connection import wait

    def running(group):
        out = []
        for proc in group:
            try:
                if not wait([proc.sentinel], 0):
                    out.append(proc)
            except (ValueError, OSError):  # a handle already closed: its process is gone
                pass
        return out

    procs = running(procs)
    for proc in procs:
        proc.terminate()
    wait([p.sentinel for p in procs], 5.0)
    stubborn = running(procs)
    for proc in stubborn:
        proc.kill()
    wait([p.sentinel for p in stubborn], 5.0)
    return len(procs)
