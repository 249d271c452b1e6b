"""The reconstruction's running record: train_log.csv (kept across a resume) and the rich
progress bar. Beside the trainer (``trase.reconstruct``) so its loop holds only training."""

from __future__ import annotations

from pathlib import Path


class TrainLog:
    """train_log.csv: iteration, smoothed loss and training PSNR, gaussian count, seconds
    since this (possibly resumed) run started, and the process CPU seconds over the same span
    (all threads; on a busy shared machine it is the fairer measure of the work done), and how
    many gaussians are static (skip the deformation network, ``trase.static_gaussians``). Rows
    past a resumed checkpoint are dropped."""

    HEADER = "iteration,loss,psnr,num_gaussians,seconds,cpu_seconds,static_gaussians\n"

    def __init__(self, path: Path, start: int) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        rows = []
        if start > 0 and path.is_file():
            for line in path.read_text().splitlines()[1:]:
                head = line.split(",", 1)[0]
                if head.isdigit() and int(head) <= start:
                    rows.append(line + "\n")
        self.f = open(path, "w")  # noqa: SIM115 - kept open for the run, closed in close()
        self.f.write(self.HEADER + "".join(rows))
        self.f.flush()

    def write(self, it: int, loss: float, psnr_db: float, n: int, seconds: float, cpu: float, static: int = 0) -> None:
        self.f.write(f"{it},{loss:.6f},{psnr_db:.4f},{n},{seconds:.2f},{cpu:.2f},{static}\n")
        self.f.flush()

    def close(self) -> None:
        self.f.close()


class ProgressBar:
    """rich progress bar with loss and PSNR (no-op when disabled)."""

    def __init__(self, enabled: bool, total: int, start: int) -> None:
        self.bar = None
        if enabled:
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
            )

            self.bar = Progress(
                TextColumn("reconstruct"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                TextColumn("{task.fields[info]}"),
            )
            self.bar.start()
            self.task = self.bar.add_task("train", total=total, completed=start, info="")

    def update(self, it: int, info: str) -> None:
        if self.bar is not None:
            self.bar.update(self.task, completed=it, info=info)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
