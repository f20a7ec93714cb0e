"""Real file systems for the storage tests: an ext4 image on a loop device
(power cuts, read-only remounts) and a small tmpfs (a full disk).

A power cut is simulated on a loop-mounted image: the writer is frozen
(SIGSTOP), then the image file is copied. The copy holds what the loop
device was given, that is, what the file system had written to its disk;
what was only in the mounted file system's page cache (written but never
synced, and not yet written back by the kernel) is not in it, as it would
not be on a disk whose power went. The copy is taken while the loop device
has no write in flight and none completes during the copy (its counters in
``/sys/block/loopN/stat`` are read before and after), so it is the disk at
one instant. Mounting the copy replays ext4's journal as a boot after a
power cut does.

Everything here needs root (mount, losetup); :func:`need_root` skips a test
that runs without it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

__all__ = ["LoopDisk", "Tmpfs", "need_root"]


def need_root() -> None:
    """Skip the calling test unless it runs as root with mount and mkfs.ext4."""
    if os.geteuid() != 0:
        pytest.skip("needs root: it mounts file systems (loop devices, tmpfs)")
    for tool in ("mount", "umount", "losetup", "mkfs.ext4"):
        if shutil.which(tool) is None:
            pytest.skip(f"needs {tool}")


def _run(*argv: str) -> str:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)}: {done.stderr.strip() or done.returncode}")
    return done.stdout


class LoopDisk:
    """An ext4 file system in ``image``, mounted at ``mountpoint`` through a loop
    device; ``umount()`` (or the end of a ``with``) detaches it."""

    def __init__(self, image: Path, mountpoint: Path, *, size_mb: int = 64,
                 fresh: bool = True, options: str = "") -> None:
        self.image, self.mountpoint = image, mountpoint
        if fresh:
            with open(image, "wb") as f:
                f.truncate(size_mb << 20)
            _run("mkfs.ext4", "-q", "-F", str(image))
        mountpoint.mkdir(parents=True, exist_ok=True)
        self.device = _run("losetup", "--find", "--show", str(image)).strip()
        try:
            _run("mount", *(["-o", options] if options else []), self.device, str(mountpoint))
        except BaseException:
            _run("losetup", "-d", self.device)
            raise
        self.mounted = True

    def __enter__(self) -> LoopDisk:
        return self

    def __exit__(self, *exc: object) -> None:
        self.umount()

    def _stat(self) -> tuple[int, int]:
        """(writes completed, I/Os in flight) of the loop device."""
        fields = Path(f"/sys/block/{Path(self.device).name}/stat").read_text().split()
        return int(fields[4]), int(fields[8])

    def power_cut(self, copy: Path, tries: int = 200) -> Path:
        """The disk as it holds now, copied to ``copy`` (the writer must be
        frozen first): taken while no write is in flight or completes."""
        for _ in range(tries):
            before = self._stat()
            if before[1] == 0:
                shutil.copyfile(self.image, copy)
                if self._stat() == before:
                    return copy
            time.sleep(0.01)
        raise RuntimeError(f"{self.device} never stood still long enough to be copied")

    def fail(self) -> None:
        """Make ext4 meet an error (its ``trigger_fs_error``): mounted with
        ``errors=remount-ro`` it turns read-only at once, flushing nothing,
        as after a failing card's I/O error."""
        name = Path(self.device).name
        Path(f"/sys/fs/ext4/{name}/trigger_fs_error").write_text("pymb test\n")

    def remount_ro(self) -> None:
        """Remount read-only (an emergency remount: writers get EROFS)."""
        _run("mount", "-o", "remount,ro", str(self.mountpoint))

    def umount(self) -> None:
        """Unmount (lazily, should a killed process still hold a file) and detach."""
        if self.mounted:
            self.mounted = False
            try:
                _run("umount", str(self.mountpoint))
            except RuntimeError:
                _run("umount", "-l", str(self.mountpoint))
            subprocess.run(["losetup", "-d", self.device], capture_output=True, timeout=60,
                           check=False)


class Tmpfs:
    """A tmpfs of ``size_kb`` at ``mountpoint`` (a disk that fills up quickly)."""

    def __init__(self, mountpoint: Path, size_kb: int) -> None:
        self.mountpoint = mountpoint
        mountpoint.mkdir(parents=True, exist_ok=True)
        _run("mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(mountpoint))
        self.mounted = True

    def __enter__(self) -> Tmpfs:
        return self

    def __exit__(self, *exc: object) -> None:
        self.umount()

    def fill(self, leave: int = 0) -> Path:
        """Fill the file system up to ``leave`` bytes free; the filler file."""
        filler = self.mountpoint / "filler"
        st = os.statvfs(self.mountpoint)
        with open(filler, "ab") as f:
            room = st.f_bavail * st.f_frsize - leave
            chunk = b"\0" * (1 << 16)
            while room > 0:
                try:
                    room -= f.write(chunk[:min(room, len(chunk))])
                    f.flush()
                except OSError:
                    break
        return filler

    def umount(self) -> None:
        """Unmount (lazily if a process still holds a file)."""
        if self.mounted:
            self.mounted = False
            try:
                _run("umount", str(self.mountpoint))
            except RuntimeError:
                _run("umount", "-l", str(self.mountpoint))
