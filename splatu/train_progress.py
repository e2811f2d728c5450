"""What training prints: a live progress bar on a terminal, plain lines off one, one line per evaluation; and the
per-view bar of every evaluation and render."""

from __future__ import annotations

import signal
from collections import Counter, deque
from collections.abc import Callable
from statistics import median

from rich.console import Console
from rich.progress import (
    BarColumn,
    Progress,
    ProgressColumn,
    Task,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Column
from rich.text import Text

from splatu.data.scene import Scene

console = Console(stderr=True)


def on_terminal() -> bool:
    """Whether the progress displays go to a terminal. Not console.is_terminal, which FORCE_COLOR (set by some CI)
    fakes: a live display would write cursor codes into the log."""
    return console.file.isatty()


PLAIN_PROGRESS_LINES = 20
"""Off a terminal a live bar draws nothing useful until the run ends (or writes cursor codes into the log, when
FORCE_COLOR is set), so plain progress lines replace it there, every 1/20 of the run and at the last step."""


class ElapsedAndRemaining(ProgressColumn):
    """`0:01:12<0:02:30`, time elapsed and time left (the task's `left`, `StepRate.seconds_left`) in one column as
    tqdm shows them: the elapsed time ticks while the first step compiles the kernels (~10 s, a minute on a cold
    cache), when nothing else on the bar moves."""

    def render(self, task: Task) -> Text:
        left = "-:--:--" if task.fields["left"] is None else _clock(task.fields["left"])
        return Text(f"{_clock(task.elapsed or 0.0)}<{left}")


def _clock(seconds: float) -> str:
    whole = int(seconds)
    return f"{whole // 3600}:{whole // 60 % 60:02d}:{whole % 60:02d}"


COMPILE_FIGURES = "compiling the kernels for the first step…"
"""What the bar shows in place of its figures while a session's first step compiles: a terminal otherwise sat on
step 0 without a word for that wait (~10 s warm, minutes cold), which COMPILE_LINE tells a log."""


class StepFigures(ProgressColumn):
    """loss (the photometric one, comparable to splatfacto's), PSNR, #G and it/s of the last step; dashes where a
    session has no step yet (`loss 0.0000 PSNR 0.00` read as figures the run had), or COMPILE_FIGURES while its first
    step compiles (the task's `compiling`)."""

    def render(self, task: Task) -> Text:
        loss, psnr, rate = (task.fields[key] for key in ("loss", "psnr", "rate"))
        if loss is None and task.fields["compiling"]:
            return Text(COMPILE_FIGURES)
        shown_loss, shown_psnr, shown_rate = (("     -", "    -", "   -") if loss is None
                                              else (f"{loss:.4f}", f"{psnr:5.2f}", f"{rate:4.1f}"))
        return Text(f"loss {shown_loss} PSNR {shown_psnr} #G {task.fields['gaussians']:>6} {shown_rate} it/s")


def progress_bar(enabled: bool) -> Progress:
    """The live bar of a terminal run (disabled off one: see PLAIN_PROGRESS_LINES). Its figures fit 80 columns with
    a few cells of bar: a wider layout lost it/s and the ETA off the end of such a terminal. A task's figures start
    as None, shown as dashes until its first step."""
    return Progress(
        TextColumn("step {task.completed:>6.0f}/{task.total:.0f}"),
        StepFigures(),
        ElapsedAndRemaining(table_column=Column(min_width=15)),  # never squeezed to "…"
        BarColumn(bar_width=None, table_column=Column(ratio=1)),
        console=console,
        expand=True,  # the bar, last, takes what the figures leave
        disable=not enabled,
    )


def view_progress(enabled: bool = True) -> Progress:
    """A transient bar for an evaluation's or a render's views (`with view_progress() as bar: bar.track(...)`): at
    full resolution one takes minutes. Shown on a terminal only, and not when `enabled` is off (--no-progress); off
    one, the eval line or the command's closing line reports the result. During training it draws under the
    training bar (rich nests live displays) and leaves nothing behind."""
    return Progress(
        TextColumn("{task.description} {task.completed:>4.0f}/{task.total:.0f} views"),
        BarColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
        disable=not (enabled and on_terminal()),
    )


def view_pass(bar: Progress, description: str, total: int) -> Callable[[], None]:
    """A new task of `bar` (a `view_progress`) for one pass over `total` views, and the callback that counts one
    view done: for a pass that runs inside a function taking an `on_view` callback (the baselines' setup)."""
    task = bar.add_task(description, total=total)
    return lambda: bar.advance(task)


COMPILE_LINE = ("compiling the rasterizer's kernels for the first step (torch.compile: about 10 s with a warm "
                "cache, a minute or more cold; --no-compile-kernels skips it)")
"""Printed off a terminal before a session's first render compiles, which otherwise leaves a log silent for that
long (on a terminal the bar's elapsed time ticks through it)."""


def eval_line(step: int, name: str, metrics: dict[str, float]) -> str:
    """One console line per evaluated set: a run's quality on screen and in its log, not only in metrics.jsonl."""
    observed = f", observed pixels {metrics['psnr_observed']:.2f} dB" if "psnr_observed" in metrics else ""
    return (f"step {step} {name} ({metrics['num_images']} views): PSNR {metrics['psnr']:.2f} dB{observed}, "
            f"SSIM {metrics['ssim']:.3f}")


def progress_line(step: int, steps: int, loss: float, psnr: float, gaussians: int, rate: float,
                  elapsed: float, left: float | None) -> str:
    """The progress bar's figures as one plain line, for output that is not a terminal (a log file, CI), where
    rich draws no bar until the end; `elapsed`: the session's seconds so far; `left`: the seconds left, None (`?`)
    before they can be told."""
    eta = "?" if left is None else _clock(round(left))
    return (f"step {step:>6}/{steps}  loss {loss:.4f}  train PSNR (EMA) {psnr:5.2f}  #G {gaussians:>7}"
            f"  {rate:5.2f} it/s  elapsed {_clock(elapsed)}  ETA {eta}")


def stopping_line(step: int | None, done: int, compiling: bool, signum: int) -> str:
    """What a training's first Ctrl-C or SIGTERM says at once (`interrupts.deferred_interrupt`): the step under way
    (`step`; None between steps, `done` the last one done) can take a minute yet, the session's first compiling the
    kernels (`compiling`), and a silent wait made users press Ctrl-C again, which aborts without saving."""
    again = f"{'Ctrl-C' if signum == signal.SIGINT else 'SIGTERM'} again aborts without saving"
    if step is None:
        return f"stopping after step {done}, once its checkpoint is saved ({again})"
    kernels = " (compiling the kernels, which can take a minute)" if compiling else ""
    return f"stopping: finishing step {step}{kernels}, then saving a checkpoint ({again})"


RATE_WINDOW = 50
"""it/s and the ETA cover the last this-many steps (at each resolution level): a mean over the whole session would
carry the first step's kernel compile (10-60 s) for the rest of the run."""


class StepRate:
    """Steps per second over the last RATE_WINDOW steps, from the times `tick` is called at, and the time the
    session's steps from `first_step` to `steps` have left. The first step of a session compiles the kernels, so
    from the second step on neither counts it. `level_at(step)` is the step's level in the trainer's resolution
    schedule (1/2^level of the images' size): a step's time grows with its image, and the steps left timed at the
    rate of the early, smaller images put the end of a short run far too early."""

    def __init__(self, now: float, first_step: int, steps: int, level_at: Callable[[int], int]) -> None:
        self.times: deque[float] = deque([now], maxlen=RATE_WINDOW + 1)
        self.compile_step_in_window = True
        self.level_at, self.step, self.first_level = level_at, first_step, level_at(first_step)
        self.steps_left = Counter(level_at(step) for step in range(first_step, steps))
        self.seconds_at: dict[int, deque[float]] = {}  # per level, its last steps' times

    def tick(self, now: float) -> float:
        """Record a finished step at time `now`; the current rate."""
        level = self.level_at(self.step)
        self.step += 1
        self.steps_left[level] -= 1
        self.seconds_at.setdefault(level, deque(maxlen=RATE_WINDOW)).append(now - self.times[-1])
        self.times.append(now)
        if self.compile_step_in_window and len(self.times) == 3:
            self.times.popleft()
            self.seconds_at[self.first_level].popleft()  # the oldest there, the compiling step's
            if not self.seconds_at[self.first_level]:  # the second step began the next level
                del self.seconds_at[self.first_level]
            self.compile_step_in_window = False
        return (len(self.times) - 1) / max(self.times[-1] - self.times[0], 1e-9)

    def seconds_left(self) -> float | None:
        """The steps left, each at the median time of the last steps at its level (not the mean, which one slow step
        moves: a level's first, which downsamples its images, or one with an evaluation after it). A level not
        reached yet (the schedule only raises the resolution) is timed as a fixed cost plus one per pixel, the two
        fitted to the current level and the one before it (the fixed part, projecting and optimising every Gaussian,
        outweighs the pixels on small images); with one level timed yet in the session, as the current level, which
        reads short. None until a step after the session's first has been timed: the first compiles the kernels, and
        timing the rest by it read 47 hours left on the main job."""
        if self.compile_step_in_window:
            return None
        current = self.level_at(self.step - 1)
        typical = {level: median(times) for level, times in self.seconds_at.items()}
        pixels = {level: 4.0 ** -level for level in self.steps_left}  # of the full-size image's
        per_pixel = 0.0
        if current + 1 in typical:
            per_pixel = (typical[current] - typical[current + 1]) / (pixels[current] - 4.0 ** -(current + 1))
        per_pixel = min(max(per_pixel, 0.0), typical[current] / pixels[current])  # neither cost below 0
        fixed = typical[current] - per_pixel * pixels[current]
        return sum(count * typical.get(level, fixed + per_pixel * pixels[level])
                   for level, count in self.steps_left.items())


def scene_line(scene: Scene) -> str:
    """What a run trains on, in one line at its start: a wrong split, size or missing point cloud shows at once,
    and so does the built-in stand-in where `--data poster` was meant as nerfstudio's capture (the one place this
    is printed: render-uncertainty and eval-ause load the scene the run was trained on)."""
    cameras = [c for views in (scene.train, scene.eval, *scene.extra_eval.values()) for c in views.cameras]
    sizes = list(dict.fromkeys(f"{c.width}x{c.height}" for c in cameras))  # each once, in the order they come
    extras = "".join(f" + {len(views)} {name}" for name, views in scene.extra_eval.items())
    points = (f"{scene.points.shape[0]:,} initial points" if scene.points.shape[0]
              else "no point cloud, so random initial points")
    stand_in = (" (the built-in stand-in, not nerfstudio's capture: put that in data/nerfstudio/poster or "
                "$SPLATU_DATA/poster to train on it)" if scene.stand_in else "")
    return (f"scene {scene.name}{stand_in}: {len(scene.train)} training and {len(scene.eval)} eval{extras} views "
            f"at {' and '.join([', '.join(sizes[:-1]), sizes[-1]] if len(sizes) > 1 else sizes)}, {points}")
