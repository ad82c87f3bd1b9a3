"""An output folder written as one: checked before any work, each file written under a
temporary name and renamed into place at the end, so a failed or interrupted run leaves the
previous outputs whole and never a mixture of two runs.

    out = OutputDir(args.out, "saarcor sim", owns=("image.png", "stats.json")).check()
    ...                                   # the run: minutes of simulation
    with out:                             # on an exception the new files are discarded
        img.save(out.file("image.png"))
        out.write_json("stats.json", stats)
    # leaving the block renamed both into place (and removed an owned file not written)

:meth:`OutputDir.check` makes the folder and proves it writable (a file named like the folder,
a read-only disk, no permission: one line naming the folder and what to do, before the run
starts). A full disk while writing raises ``OSError``; ``saarcor`` prints it as one line
(``saarcor.cli``) and the previous outputs stay as they were.
"""
from __future__ import annotations

import json
import os
import signal
import threading
from pathlib import Path

__all__ = ["OutputDir", "OutputError"]


class OutputError(SystemExit):
    """The output folder cannot be used; the message names it and what to do."""


class OutputDir:
    """An output folder whose files appear together (see the module docstring).

    ``owns``: the names this command writes there; :meth:`commit` removes one of them that this
    run did not write (a ``usage.png`` of an earlier run beside this run's ``stats.json`` would
    be a mixture)."""

    PARTIAL = ".partial-"

    def __init__(self, path: str | Path, prog: str = "saarcor", owns: tuple[str, ...] = ()):
        self.dir = Path(path)
        self.prog = prog
        self.owns = tuple(owns)
        self._staged: dict[str, Path] = {}

    # -- before the run -----------------------------------------------------------------------
    def check(self) -> "OutputDir":
        """Make the folder and prove a file can be written in it; exits with one line naming
        the problem otherwise. Returns ``self``."""
        d = self.dir
        if d.exists() and not d.is_dir():
            raise OutputError(f"{self.prog}: --out {d} is a file, not a folder; name a folder "
                              "(it is made if missing)")
        try:
            d.mkdir(parents=True, exist_ok=True)
            probe = d / f"{self.PARTIAL}{os.getpid()}.probe"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as e:
            raise OutputError(f"{self.prog}: cannot write to --out {d}: "
                              f"{e.strerror or e}; choose a writable folder") from None
        self._clean_stale()
        return self

    def _clean_stale(self) -> None:
        """Remove temporary files an earlier, killed run left (its process is gone)."""
        for p in self.dir.glob(f"{self.PARTIAL}*"):
            pid = p.name[len(self.PARTIAL):].split(".", 1)[0]
            if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)):
                p.unlink(missing_ok=True)

    # -- writing ------------------------------------------------------------------------------
    def file(self, name: str) -> Path:
        """The temporary path to write ``name`` to; it keeps ``name``'s suffix, so a writer
        that picks its format from the suffix (Pillow, matplotlib, ``np.savez``) works."""
        if "/" in name or name.startswith("."):
            raise ValueError(f"OutputDir.file({name!r}): a plain file name")
        tmp = self.dir / f"{self.PARTIAL}{os.getpid()}.{name}"
        self._staged[name] = tmp
        return tmp

    def write_text(self, name: str, text: str) -> None:
        self.file(name).write_text(text)

    def write_json(self, name: str, obj, **kw) -> None:
        self.write_text(name, json.dumps(obj, indent=kw.pop("indent", 1), **kw))

    def commit(self) -> list[Path]:
        """Rename every staged file into place and remove owned files not written; returns
        the final paths."""
        done = []
        block = threading.current_thread() is threading.main_thread()
        if block:                        # a Ctrl-C waits until every file is in place
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            for name, tmp in self._staged.items():
                final = self.dir / name
                os.replace(tmp, final)
                done.append(final)
            for name in self.owns:
                if name not in self._staged:
                    (self.dir / name).unlink(missing_ok=True)
            self._staged.clear()
        finally:
            if block:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        return done

    def discard(self) -> None:
        """Remove the staged files (the previous outputs are untouched)."""
        for tmp in self._staged.values():
            tmp.unlink(missing_ok=True)
        self._staged.clear()

    def __enter__(self) -> "OutputDir":
        return self

    def __exit__(self, kind, value, tb) -> None:
        if kind is None:
            self.commit()
        else:
            self.discard()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def write_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename: a
    failed or interrupted write leaves the previous file whole (one file; several files that
    belong together: :class:`OutputDir`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f"{OutputDir.PARTIAL}{os.getpid()}.{path.name}"
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def check_out(path: str | Path, prog: str) -> Path:
    """The ``--out`` folder made and proved writable before a long run (one line naming the
    problem otherwise: :meth:`OutputDir.check`)."""
    return OutputDir(path, prog).check().dir
