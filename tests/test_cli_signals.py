"""The ``glacimap`` entry point as a shell sees it: Ctrl-C (a real SIGINT to a real process), exit
codes, and stdout redirected to a file."""

import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import typer
from rich.console import Console

import toolkit.cli as cli
import toolkit.cli._interrupt as cli_interrupt
from toolkit.cli._progress import stage_progress

ROOT = Path(__file__).resolve().parents[1]


def _start(args: list[str], cwd: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT), COLUMNS="100")
    return subprocess.Popen(
        [sys.executable, "-m", "toolkit", *args],
        cwd=cwd,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        # A shell without job control starts background jobs with SIGINT ignored, and Python
        # keeps an inherited SIG_IGN: restore the default so the CLI's own handling is tested
        # however pytest was launched (e.g. `make test &`).
        preexec_fn=_default_sigint,
    )


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait_until_running(proc: subprocess.Popen, out: Path, timeout: float = 120.0) -> None:
    """Wait until the command has made its output folder (it is past start-up, in its work)."""
    t0 = time.monotonic()
    while not out.is_dir():
        assert proc.poll() is None, f"ended early: {proc.returncode} {proc.stderr.read()}"
        assert time.monotonic() - t0 < timeout, f"no {out} after {timeout} s"
        time.sleep(0.1)
    time.sleep(2.0)  # well inside the work (simulation / iSAM2 / GP fit), not in start-up


def _products(out: Path) -> list[str]:
    return sorted(p.name for p in out.rglob("*") if p.is_file()) if out.exists() else []


def _interrupt(args: list[str], cwd: Path, out: Path) -> tuple[int, str]:
    """Start ``glacimap ARGS``, send SIGINT once it is at work, return its exit code and
    stderr."""
    proc = _start(args, cwd)
    try:
        _wait_until_running(proc, out)
        os.kill(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, err


@pytest.mark.parametrize(
    "args",
    [["run", "--out", "o"], ["reconstruct", "--demo", "--out", "o"]],  # iSAM2 / the GP fit
    ids=["run", "reconstruct"],
)
def test_sigint_exits_130_with_one_line_and_no_product(tmp_path, args):
    rc, err = _interrupt(args, tmp_path, tmp_path / "o")
    assert rc == 130, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "interrupted" in lines[0], err
    assert "Traceback" not in err
    left = _products(tmp_path / "o")
    assert not left, f"interrupted {args[0]} left files (temporary ones included): {left}"


@pytest.mark.parametrize("code", [0, 3, 130])
def test_main_passes_on_the_exit_code_a_command_sets(monkeypatch, capsys, code):
    """typer returns (does not raise) Exit codes when not standalone: main must pass them on."""
    probe = typer.Typer()

    @probe.command()
    def stop() -> None:
        raise typer.Exit(code)

    monkeypatch.setattr(cli, "app", probe)
    monkeypatch.setattr(sys, "argv", ["glacimap"])
    monkeypatch.setattr(cli, "leave_now", sys.exit)  # in-process: not os._exit
    with pytest.raises(SystemExit) as exc:
        cli.main()
    assert exc.value.code == code
    assert ("interrupted" in capsys.readouterr().err) == (code == 130)


def test_main_turns_keyboard_interrupt_into_130(monkeypatch):
    probe = typer.Typer()

    @probe.command()
    def stop() -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "app", probe)
    monkeypatch.setattr(sys, "argv", ["glacimap"])
    left = []
    monkeypatch.setattr(cli, "leave_now", lambda code: left.append(code) or sys.exit(code))
    with pytest.raises(SystemExit) as exc:
        cli.main()
    assert exc.value.code == 130 and left == [130]  # Ctrl-C skips the interpreter's teardown


@pytest.fixture
def python_sigint():
    """Python's own SIGINT handler in this process for the test: a shell without job control
    starts background jobs (`make test &`) with SIGINT ignored, and Python keeps that."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _swallowed_ctrl_c() -> None:
    """A real SIGINT to this process, caught where a library's bare ``except:`` would."""
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(5.0)  # the handler raises in here
    except KeyboardInterrupt:
        pass
    else:
        raise AssertionError("the SIGINT never raised")


def test_a_ctrl_c_a_library_swallowed_stops_the_run_at_its_next_progress_step(python_sigint):
    """What lost the `run` SIGINT test's interrupt about one run in five: pynmea2 converts the
    NMEA fields inside a bare ``except:``. Whatever swallows it, the next progress callback of
    the stage bar raises it again."""
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with cli_interrupt.catching_ctrl_c() as seen:
        _swallowed_ctrl_c()
        assert cli_interrupt.interrupted()
        with stage_progress(Console(file=io.StringIO()), ("localize",)) as (on_stage, on_step):
            with pytest.raises(KeyboardInterrupt):
                on_step(1, 10)
            with pytest.raises(KeyboardInterrupt):
                on_stage("localize", "done")
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
    assert seen.came
    # The remembered interrupt ends with the block: a later command in the same process
    # (tests run `process` in-process after this one) must not stop at its first step.
    assert not cli_interrupt.interrupted()
    cli_interrupt.raise_if_interrupted()
    with cli_interrupt.catching_ctrl_c() as again:
        assert not cli_interrupt.interrupted()
    assert not again.came


@pytest.mark.parametrize("ending", ["returns", "import_error"])
def test_main_reports_any_ending_after_a_ctrl_c_as_interrupted(
    monkeypatch, capsys, ending, python_sigint
):
    """A pybind11 module (GTSAM) interrupted while it initialises raises ``ImportError:
    initialization failed``: that printed a traceback and exited 1 instead of 130."""
    probe = typer.Typer()

    @probe.command()
    def stop() -> None:
        _swallowed_ctrl_c()
        if ending == "import_error":
            raise ImportError("initialization failed")

    monkeypatch.setattr(cli, "app", probe)
    monkeypatch.setattr(sys, "argv", ["glacimap"])
    monkeypatch.setattr(cli, "leave_now", sys.exit)
    with pytest.raises(SystemExit) as exc:
        cli.main()
    assert exc.value.code == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err


def test_print_default_redirected_to_a_file_is_the_scenario_byte_for_byte(tmp_path):
    """Issue 17: `glacimap run --print-default > my.toml` wrapped comments at 80 columns (rich,
    stdout not a terminal), and the file did not parse."""
    from toolkit.config import DEFAULT_SCENARIO, DEFAULT_TOML, load_scenario

    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    env["PYTHONPATH"] = str(ROOT)
    target = tmp_path / "my.toml"
    with target.open("w") as fh:
        rc = subprocess.run(
            [sys.executable, "-m", "toolkit", "run", "--print-default"],
            cwd=tmp_path,
            env=env,
            stdout=fh,
            stderr=subprocess.PIPE,
            timeout=120,
        ).returncode
    assert rc == 0
    text = target.read_text()
    assert max(len(line) for line in DEFAULT_TOML.splitlines()) > 80  # would have wrapped
    assert text == DEFAULT_TOML
    assert load_scenario(target) == load_scenario(None) == DEFAULT_SCENARIO


def test_interrupt_while_writing_the_field_files_leaves_none(tmp_path, monkeypatch):
    """Ctrl-C while ``run`` writes the simulated field folder (measured: a SIGINT landing
    there under load left gps.nmea, odometry.csv, tilt.csv and checkpoints.csv behind)."""
    import toolkit.pipeline as pipeline

    real = pipeline.write_field_survey

    written = []

    def interrupted(scenario, truth, log, folder, **kw):
        real(scenario, truth, log, folder, **kw)  # every file written, then Ctrl-C
        written.extend(p.name for p in Path(folder).rglob("*.nmea"))
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline, "write_field_survey", interrupted)
    small = {"plan": {"n_swaths": 1}}
    with pytest.raises(KeyboardInterrupt):
        pipeline.run_scenario(out=tmp_path / "o", overrides=small)
    assert written == ["gps.nmea"] and _products(tmp_path / "o") == []


def test_ctrl_c_does_not_wait_for_a_stuck_worker_thread(tmp_path):
    """A pool worker left waiting by the interrupt (here: on an event no one will set) kept the
    interpreter's teardown, hence the process, alive for ever; after Ctrl-C ``main`` leaves at
    once. Without :func:`toolkit.cli.leave_now` this child never exits (the timeout fails)."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import sys, threading, typer\n"
        "import toolkit.cli as cli\n"
        "app = typer.Typer()\n"
        "@app.command()\n"
        "def stuck() -> None:\n"
        "    threading.Thread(target=threading.Event().wait).start()  # not a daemon\n"
        "    raise KeyboardInterrupt\n"
        "cli.app = app\n"
        "sys.argv = ['glacimap']\n"
        "cli.main()\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, str(probe)], env=env, stderr=subprocess.PIPE, text=True
    )
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
