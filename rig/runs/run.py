"""The run engine: one recorded procedure run, and the safe stop it owns.

    with Run("identify", parameters=params, config=cfg, seed=7) as run:
        arm = run.claim(psm1)                     # held on any exit
        with run.step("excite", total=n) as step:
            for k in range(n):
                ...; run.recorder.joint_state("/PSM1/measured_js", t, q, dq, tau)
                step.advance()
        run.finish({"summary": {...}, ...})
    emit_result(run.result, as_json)

On entry the run creates `runs_root()/<UTC time>-<procedure>/`, opens `run.mcap` and
writes `run_start`. On exit, whatever the reason, it

1. puts every claimed arm in its safe state (`hold()`), each in its own try, so a failing
   hold is reported but never hides the original error nor skips the other arms;
2. closes the recording with `run_stop` (status, error, counts);
3. writes `result.json` (the procedure's result plus status, procedure, run_dir, timings);
4. re-raises the exception, if any.

Status: "completed" on a normal exit; "aborted" for AbortRun (safety checks raise it with
a reason), Ctrl-C (KeyboardInterrupt) and SIGTERM (converted to AbortRun while the run is
active); "failed" for any other exception. Signals arriving while the run is finalising are
reported and deferred, so a second Ctrl-C cannot cut the file short.
"""

from __future__ import annotations

import functools
import signal
import sys
import threading
import time
from contextlib import contextmanager
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Iterator, TextIO

from rig.faults import DeviceFault
from rig.runs import run_owner
from rig.runs.compile_notice import CompileWatch
from rig.runs.paths import run_dir_name, runs_root
from rig.runs.recording import Recorder
from rig.sealed_json import seal_provenance, write_result

#: statuses a procedure may declare for a run that ended without an exception
DECLARED_STATUSES = ("completed", "failed", "dry-run")


class AbortRun(Exception):
    """Stop the run safely: a limit was hit, a sensor went stale, the user asked.

    `reason` is one line for a person ("joint 2 velocity 1.9 rad/s above limit 1.5");
    `arm`, `joint` (1-3) and `limit` (which limit: "velocity", "effort", "tension", ...) the
    same for a program, where the check knows them (`fields()`, as rig.faults.DeviceFault's).
    The run engine sets `run_dir` when the exception leaves a Run.
    """

    def __init__(self, reason: str, *, arm: str | None = None, joint: int | None = None, limit: str | None = None):
        super().__init__(reason)
        self.reason = reason
        self.arm, self.joint, self.limit = arm, joint, limit
        self.state = None
        self.run_dir: Path | None = None

    def fields(self) -> dict:
        return {k: getattr(self, k) for k in ("arm", "state", "joint", "limit") if getattr(self, k) is not None}


class Step:
    """Progress of one named step; `advance()` as work is done (see Run.step)."""

    def __init__(self, run: "Run", name: str, index: int, total: int | None):
        self.run, self.name, self.index, self.total = run, name, index, total
        self.done = 0
        self.started = time.monotonic()
        self._last_print = 0.0
        self._last_decile = 0

    def advance(self, n: int = 1) -> None:
        self.done += n
        self._show()

    def update(self, done: int) -> None:
        self.done = done
        self._show()

    def _show(self, final: bool = False) -> None:
        if self.total is None or not self.run.progress:
            return
        now = time.monotonic()
        fraction = min(self.done / self.total, 1.0) if self.total else 1.0
        tty = self.run._stream_is_tty
        # Redraw a terminal line at most 10 times a second; in a log file print a line
        # per 10 % so CI logs show progress without thousands of lines.
        if tty and not final and now - self._last_print < 0.1:
            return
        decile = int(10 * fraction + 1e-9)
        if not tty and not final and decile <= self._last_decile:
            return
        self._last_print, self._last_decile = now, decile
        width = 24
        bar = "#" * int(width * fraction) + "-" * (width - int(width * fraction))
        line = (f"{self.run._label(self)} [{bar}] {self.done}/{self.total} "
                f"{now - self.started:6.1f} s")
        if tty:
            self.run._write("\r" + line + ("\n" if final else ""))
        elif not final:
            self.run._write(line + "\n")


class Run:
    """A recorded procedure run; use as a context manager (see the module docstring).

    Args:
        procedure: procedure name, used in the folder name and the start record.
        parameters: the procedure's parameters (a ParameterSet gives units too).
        config: the rig configuration snapshot (anything JSON-serialisable).
        seed: the random seed of the simulated rig, if any.
        steps: the procedure's step names, to number steps as "[2/5]".
        root: parent folder of the run folder (default: `runs_root()`).
        progress: print steps and progress to `stream` (stderr).
        recorder_options: passed to Recorder (compression, chunk_size, queue_limit).
    """

    def __init__(self, procedure: str, parameters: dict | None = None, config: Any = None,
                 seed: Any = None, *, steps: list[str] | None = None, root: Path | None = None,
                 progress: bool = True, stream: TextIO | None = None,
                 recorder_options: dict | None = None):
        if not procedure or "/" in procedure or procedure != procedure.strip():
            raise ValueError(f"procedure name must be a plain word, got {procedure!r}")
        self.procedure = procedure
        self.parameters = parameters if parameters is not None else {}
        self.config = config
        self.seed = seed
        self.steps = list(steps) if steps else None
        self.root = Path(root) if root is not None else None
        self.progress = progress
        self.stream = stream
        self.recorder_options = recorder_options or {}
        self.dir: Path | None = None
        self.recorder: Recorder | None = None
        self.result: dict | None = None
        self._declared: tuple[str, str | None] | None = None  # (status, reason) from finish()
        self.status: str | None = None
        self._claimed: list = []
        self._step_times: dict[str, float] = {}
        self._current_step: Step | None = None
        self._step_count = 0
        self._old_handlers: dict[int, Any] = {}
        self._finalising = False
        self._deferred_signals: list[str] = []
        self._compile_watch = CompileWatch(self._compile_note)

    # ------------------------------------------------------------------ the run
    def __enter__(self) -> "Run":
        root = self.root if self.root is not None else runs_root()
        root.mkdir(parents=True, exist_ok=True)
        self.utc_start = datetime.now(timezone.utc)
        self._t0 = time.monotonic()
        while True:  # two runs in the same microsecond: take the next microsecond
            candidate = root / run_dir_name(self.procedure, self.utc_start)
            try:
                candidate.mkdir()
                break
            except FileExistsError:
                self.utc_start += timedelta(microseconds=1)
        self.dir = candidate
        run_owner.claim(self.dir)  # released once the run's files are written (rig.runs.run_owner)
        self.recorder = Recorder(self.dir / "run.mcap", **self.recorder_options)
        describe = getattr(self.parameters, "describe", None)
        self.recorder.start(self.procedure,
                            parameters=describe() if callable(describe) else self.parameters,
                            config=self.config, seed=self.seed, utc_start=self.utc_start,
                            extra={"run_dir": str(self.dir)})
        self._stream_is_tty = bool(getattr(self._out(), "isatty", lambda: False)())
        self._install_signal_handlers()
        self._write(f"rig {self.procedure}: recording to {self.dir}\n")
        self._watch_compiles()
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        self._finalising = True
        self._defer_signals()
        try:
            self._finalise(exc)
        finally:
            self._restore_signal_handlers()
            self._unwatch_compiles()
        return False  # never swallow: the caller (or exit_on_abort) decides what to show

    def claim(self, arm):
        """Remember an arm this run moves; it gets `hold()` when the run ends. Returns it."""
        if not any(a is arm for a in self._claimed):
            self._claimed.append(arm)
        return arm

    @property
    def claimed(self) -> list:
        return list(self._claimed)

    @contextmanager
    def step(self, name: str, total: int | None = None) -> Iterator[Step]:
        """A named step with optional progress (`total` units of work, `advance()` each).

        Prints the step on start and end to stderr and times it into result.json.
        """
        self._step_count += 1
        step = Step(self, name, self._step_count, total)
        self._current_step = step
        self._write(f"{self._label(step)} ...\n")
        self._watch_compiles()  # numba may have been imported since the run began
        ok = False
        try:
            yield step
            ok = True
        finally:
            elapsed = time.monotonic() - step.started
            self._step_times[name] = round(self._step_times.get(name, 0.0) + elapsed, 6)
            step._show(final=True)
            self._write(f"{self._label(step)} {'done' if ok else 'stopped'} in {elapsed:.2f} s\n")
            if ok:
                self._current_step = None

    def finish(self, result: dict, status: str = "completed", reason: str | None = None) -> dict:
        """Set the procedure's result; returns the result document (updated on exit with
        status and timings, and written to result.json when the run ends).

        `status`: how the run ended if nothing raised: "completed", "failed" (it ran to its
        end without meeting what it exists for; `reason` says what was missed) or "dry-run"
        (planned, nothing moved). It goes to result.json and the recording's stop record.
        """
        if not isinstance(result, dict):
            raise TypeError(f"the result must be a dict, got {type(result).__name__}")
        if status not in DECLARED_STATUSES:
            raise ValueError(f"status must be one of {DECLARED_STATUSES}, got {status!r}")
        self.result = result
        self._declared = (status, reason)
        return self.result

    def elapsed(self) -> float:
        """Seconds since the run started (monotonic wall clock)."""
        return time.monotonic() - self._t0

    # ------------------------------------------------------------- finalising
    def _finalise(self, exc: BaseException | None) -> None:
        status, reason = classify(exc)
        if exc is None and self._declared is not None:
            status, reason = self._declared
        self.status = status
        stopped_in = self._current_step.name if (exc is not None and self._current_step) else None
        held, hold_errors = self._hold_all()
        for err in hold_errors:
            if err.get("state"):
                self._write(f"rig {self.procedure}: {err['arm']} not held: {err['error']}\n")
            else:
                self._write(f"rig {self.procedure}: could not hold {err['arm']}: {err['error']}\n")
        stop_extra = {"held": held, "hold_errors": hold_errors, "steps": self._step_times}
        if stopped_in:
            stop_extra["step"] = stopped_in
        fault = fault_fields(exc)
        if fault:
            stop_extra["fault"] = fault
        recorder_error = None
        try:
            self.recorder.close(status, reason, extra=stop_extra)
        except Exception as err:  # reported in result.json; the original error still wins
            recorder_error = f"{type(err).__name__}: {err}"
            self._write(f"rig {self.procedure}: the recording could not be finished: {recorder_error}\n")
            if status in ("completed", "dry-run"):  # a run without its record did not do its job
                status, reason = "failed", recorder_error
                self.status = status
        utc_stop = datetime.now(timezone.utc)
        doc = self.result if self.result is not None else {}
        doc.update({
            "status": status,
            "procedure": self.procedure,
            "run_dir": str(self.dir),
            "timings": {"utc_start": self.utc_start.isoformat(), "utc_stop": utc_stop.isoformat(),
                        "duration_s": round(self.elapsed(), 6), "steps": self._step_times},
        })
        if status not in ("completed", "dry-run"):
            doc["error"] = reason
            if stopped_in:
                doc["step"] = stopped_in
            if fault:
                doc["fault"] = fault
        tick = self._loop_timing()
        if tick:
            doc.setdefault("loop_tick", tick)
        if held:
            doc["held"] = held
        if hold_errors:
            doc["hold_errors"] = hold_errors
        if recorder_error:
            doc["recording_error"] = recorder_error
        seal_provenance(doc)
        self.result = doc
        try:
            write_result(self.dir / "result.json", doc)
        except Exception as err:
            if exc is None:
                raise
            # the original error is the one to see; this one is secondary
            self._write(f"rig {self.procedure}: could not write result.json: {err}\n")
        run_owner.release(self.dir)
        if tick:
            self._write(f"rig {self.procedure}: loop on {tick['clock']}: {tick['tick_median_ms']:.2f} ms a tick "
                        f"(median; p99 {tick['tick_p99_ms']:.2f} ms) against its {tick['period_ms']:.1f} ms period, "
                        f"longer on {tick['over_period']} of {tick['ticks']} ticks\n")
        if exc is not None:
            try:  # lets exit_on_abort name the folder for Ctrl-C and failures too
                exc.run_dir = self.dir
            except AttributeError:
                pass
        if status == "completed":
            self._write(f"rig {self.procedure}: completed in {self.elapsed():.1f} s ({self.dir})\n")

    def _loop_timing(self) -> dict:
        """How long the procedure took per tick of its loop, against the loop's period, and
        which clock it ran on: from the clock of the arms it moved (`clock.loop_timing()`;
        {} when it never looped)."""
        clock = next((a.clock for a in self._claimed if getattr(a, "clock", None) is not None), None)
        timing = getattr(clock, "loop_timing", None)
        if timing is None:
            return {}
        out = timing()
        if out:
            time_base = getattr(clock, "time", None)
            out["clock"] = (time_base.describe() if time_base is not None and hasattr(time_base, "describe")
                            else "the simulated world (in process)" if hasattr(clock, "world") else "the wall clock")
        return out

    def _hold_all(self) -> tuple[list[str], list[dict]]:
        """Hold every claimed arm: (names held, [{"arm", "error"[, "state"]}] of the others).

        An arm whose operating state says it obeys no command (a dVRK arm in FAULT,
        DISABLED or PAUSED: its drives are off or its commands ignored) takes the hold
        command without an error but is not held: it goes to the errors with its state."""
        held, errors, commanded = [], [], []
        for arm in self._claimed:
            name = str(getattr(arm, "name", type(arm).__name__))
            try:
                arm.hold()
            except BaseException as err:  # noqa: BLE001 - one arm failing must not spare the rest
                errors.append({"arm": name, "error": f"{type(err).__name__}: {err}"})
                continue
            commanded.append((name, arm))
        for name, arm in commanded:
            state = _disobeying_state(arm)
            if state is None:
                held.append(name)
            else:
                errors.append({"arm": name, "state": state,
                               "error": f"{name} is {state}: it obeys no command, the hold included "
                                        "(a person clears it at the dVRK console)"})
        return held, errors

    # ------------------------------------------------------------------ signals
    def _install_signal_handlers(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return  # Python delivers signals to the main thread only; its owner handles them

        def on_sigterm(signum, frame):
            if self._finalising:
                self._note_deferred("SIGTERM")
                return
            raise AbortRun("SIGTERM received (the process was asked to stop)")

        self._old_handlers[signal.SIGTERM] = signal.signal(signal.SIGTERM, on_sigterm)

        # Ctrl-C stays a KeyboardInterrupt, but one that checks the flag, so a second
        # Ctrl-C at the very start of the safe stop is deferred too. A handler someone
        # else installed (or SIG_IGN) is left alone.
        def on_sigint(signum, frame):
            if self._finalising:
                self._note_deferred("SIGINT")
                return
            raise KeyboardInterrupt

        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self._old_handlers[signal.SIGINT] = signal.signal(signal.SIGINT, on_sigint)

    def _defer_signals(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return

        def later(signum, frame):
            self._note_deferred(signal.Signals(signum).name)

        for sig in (signal.SIGINT, signal.SIGTERM):
            previous = signal.signal(sig, later)
            self._old_handlers.setdefault(sig, previous)

    def _note_deferred(self, name: str) -> None:
        self._deferred_signals.append(name)
        self._write(f"rig {self.procedure}: {name} while making the arms safe and closing "
                    f"the recording; finishing first\n")

    def _restore_signal_handlers(self) -> None:
        for sig, handler in self._old_handlers.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        self._old_handlers.clear()

    # ------------------------------------------------------ first-use compilation
    def _watch_compiles(self) -> None:
        """Say in the progress lines when numba compiles a kernel (rig.runs.compile_notice)."""
        if self.progress:
            self._compile_watch.start()

    def _unwatch_compiles(self) -> None:
        self._compile_watch.stop()

    def _compile_note(self, name: str, seconds: float | None) -> None:
        step = self._current_step
        where = f"{self._label(step)}:" if step is not None else f"rig {self.procedure}:"
        # a terminal's progress bar is redrawn in place: leave its line first
        lead = "\n" if step is not None and step.total is not None and self._stream_is_tty else ""
        if seconds is None:
            self._write(f"{lead}{where} compiling {name} (numba, first use after an install or upgrade: "
                        "tens of seconds with no progress; later runs load it from numba's cache) ...\n")
        else:
            self._write(f"{where} compiled {name} in {seconds:.1f} s\n")

    # ------------------------------------------------------------------ output
    def _out(self) -> TextIO:
        return self.stream if self.stream is not None else sys.stderr

    def say(self, line: str) -> None:
        """A line for the person running the procedure (stderr, with the steps; not with
        progress off)."""
        self._write(line if line.endswith("\n") else line + "\n")

    def _write(self, text: str) -> None:
        if not self.progress:
            return
        try:
            out = self._out()
            out.write(text)
            out.flush()
        except (OSError, ValueError):  # a closed or broken stderr must not break the run
            pass

    def _label(self, step: Step) -> str:
        of = f"/{len(self.steps)}" if self.steps else ""
        return f"[{step.index}{of}] {step.name}"


#: how long the end of a run waits for an arm's answer to "what is your operating state?"
#: (s). The dVRK publishes the state on change only; a FAULT an instant before another
#: device's fault ended the run may still be on its way, and a held arm must be one that
#: obeys. rig sim answers within a few ms; a dead console does not answer at all.
CONFIRM_STATE_WAIT = 0.3


def _disobeying_state(arm) -> str | None:
    """The operating state of an arm that obeys no command (not ENABLED and homed), as
    "FAULT, homed", asked of the arm when it can be (`confirm_state`); None when it obeys,
    or it reports no state (the in-process arms)."""
    get = getattr(arm, "confirm_state", None)
    if callable(get):
        get = functools.partial(get, CONFIRM_STATE_WAIT)
    else:
        get = getattr(arm, "operating_state", None)
    if not callable(get):
        return None
    try:
        st = get()
    except Exception:  # noqa: BLE001 - a state that cannot be read says nothing against the hold
        return None
    if st is None or getattr(st, "ready", True):
        return None
    describe = getattr(st, "describe", None)
    return describe() if callable(describe) else str(getattr(st, "state", st))


def fault_fields(exc: BaseException | None) -> dict:
    """What ended a run, for a program: the arm, its state, the joint and the limit (an
    AbortRun's or a DeviceFault's `fields()`); {} for anything else."""
    return exc.fields() if isinstance(exc, (AbortRun, DeviceFault)) else {}


def classify(exc: BaseException | None) -> tuple[str, str | None]:
    """(status, reason) for how a run ended."""
    if exc is None:
        return "completed", None
    if isinstance(exc, AbortRun):
        return "aborted", exc.reason
    if isinstance(exc, KeyboardInterrupt):
        return "aborted", "interrupted (Ctrl-C)"
    if isinstance(exc, SystemExit):
        return "aborted", f"exit requested (code {exc.code})"
    if isinstance(exc, DeviceFault):
        return "aborted", str(exc)
    text = str(exc)
    return "failed", f"{type(exc).__name__}: {text}" if text else type(exc).__name__
