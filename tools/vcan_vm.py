#!/usr/bin/env python3
"""Run cablebot's real-SocketCAN tests (pytest -m vcan) natively or inside a virtme-ng VM.

Sub-commands (stdlib only; run it with any Python >= 3.9):

``test [PYTEST_ARGS...]``  (what ``make test-vcan`` runs)
    1. If the kernel here has SocketCAN and ``vcan0`` is up (or can be created: root + module),
       run ``pytest -m vcan`` natively.
    2. Else, if qemu is installed, make sure the no-root tools exist (a virtme-ng venv and a
       Debian kernel, both cached under ``~/.cache/cablebot``), boot a VM with that kernel and
       the host's file system shared, create ``vcan0`` in it and run ``pytest -m vcan`` there.
       The guest's output is streamed to stdout; the result comes from a file the guest writes
       (``vng`` itself exits 255 even on success).
    3. Else print a loud SKIPPED banner saying how to get the tools; exit 1 under ``CI=true``
       (CI must prove the vcan tests ran), else 0.

``bench [ARGS...]``  (what ``make bench-vcan`` runs)
    The SocketCAN I/O benchmark (``python -m controller.cli.bench_vcan``) natively or in the
    same VM; writes ``bench-vcan.json`` at the top of the checkout.

``tools [--apt]``  (what ``make vcan-tools`` runs; idempotent)
    With ``--apt`` and root: ``apt-get install`` the missing qemu-system-x86 kmod busybox-static
    iproute2. Always: the virtme-ng tool venv and the current Debian ``linux-image-*-amd64``
    (found with ``apt-cache depends linux-image-amd64``) extracted into the cache.

Environment:
    CABLEBOT_VCAN_MODE     auto (default) | native | vm | skip
    CABLEBOT_VCAN_TIMEOUT_S  wall-clock limit of the VM run (default 2400)
    CABLEBOT_VCAN_CPUS / CABLEBOT_VCAN_MEMORY   guest size (default 2 CPUs, 2G)
    CABLEBOT_VCAN_KVM=1    try KVM (hangs or aborts on this kind of machine; off by default)
    CABLEBOT_CACHE         cache folder (default ${XDG_CACHE_HOME:-~/.cache}/cablebot)
    CI=true                a skip is a failure
"""

from __future__ import annotations

import argparse
import fcntl
import os
import platform
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
APT_PACKAGES = ("qemu-system-x86", "kmod", "busybox-static", "iproute2")
# The commands each package provides (how we tell it is installed).
APT_PROBES = {
    "qemu-system-x86": "qemu-system-x86_64",
    "kmod": "modprobe",
    "busybox-static": "busybox",
    "iproute2": "ip",
}
SBIN_PATHS = ("/usr/local/sbin", "/usr/sbin", "/sbin")
CAN_MODULES = ("vcan", "can", "can_raw", "can_bcm")
VCAN = "vcan0"


# --------------------------------------------------------------------------- helpers


def log(msg: str) -> None:
    """Print one progress line of this tool (flushed, so it interleaves with make's output)."""
    print(f"[vcan] {msg}", flush=True)


def is_ci() -> bool:
    """True when ``CI`` says we run under continuous integration."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


def cache_dir() -> Path:
    """The folder holding the tool venv and kernels (outside the repo)."""
    explicit = os.environ.get("CABLEBOT_CACHE")
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "cablebot"


def which(cmd: str) -> str | None:
    """Find ``cmd`` on PATH or in the sbin folders (which a non-root PATH often lacks)."""
    found = shutil.which(cmd)
    if found:
        return found
    return shutil.which(cmd, path=os.pathsep.join(SBIN_PATHS))


def run_quiet(cmd: list[str], timeout_s: float = 600.0) -> subprocess.CompletedProcess[str]:
    """Run a command capturing its output; never raises for a non-zero exit or a timeout."""
    try:
        return subprocess.run(
            cmd,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return subprocess.CompletedProcess(cmd, 127, "", str(exc))


def banner(lines: list[str]) -> None:
    """Print a loud framed multi-line message."""
    bar = "#" * 78
    print(bar, flush=True)
    for line in lines:
        print(f"# {line}", flush=True)
    print(bar, flush=True)


# --------------------------------------------------------------------------- native vcan


def vcan_usable() -> tuple[bool, str]:
    """Whether a raw CAN socket can be bound to vcan0 on this kernel, and why not."""
    if not hasattr(socket, "AF_CAN"):
        return False, "Python has no AF_CAN"
    try:
        sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as exc:
        return False, f"the kernel has no SocketCAN ({exc.strerror})"
    try:
        sock.bind((VCAN,))
    except OSError as exc:
        return False, f"no {VCAN} interface ({exc.strerror})"
    finally:
        sock.close()
    return True, f"{VCAN} is up"


def try_create_native_vcan() -> tuple[bool, str]:
    """As root, try ``modprobe vcan`` and create + raise vcan0; report whether it is usable."""
    ok, reason = vcan_usable()
    if ok:
        return ok, reason
    if os.geteuid() != 0:
        return False, reason + "; not root, so not trying to create it"
    modprobe, ip = which("modprobe"), which("ip")
    if modprobe is None or ip is None:
        return False, reason + "; modprobe/ip missing"
    run_quiet([modprobe, "-a", *CAN_MODULES], timeout_s=30)
    if not Path(f"/sys/class/net/{VCAN}").exists():
        run_quiet([ip, "link", "add", "dev", VCAN, "type", "vcan"], timeout_s=30)
    run_quiet([ip, "link", "set", "up", VCAN], timeout_s=30)
    return vcan_usable()


# --------------------------------------------------------------------------- VM tools


def vng_venv() -> Path:
    """The tool venv holding virtme-ng."""
    return cache_dir() / "vng-venv"


def vng_path() -> Path | None:
    """The ``vng`` executable of the tool venv, if installed."""
    path = vng_venv() / "bin" / "vng"
    return path if path.exists() and (vng_venv() / "bin" / "virtme-run").exists() else None


def kernel_root() -> Path:
    """Folder of extracted kernels, one sub-folder per kernel release."""
    return cache_dir() / "kernel"


def cached_kernels() -> list[Path]:
    """Complete extracted kernels, newest release first."""
    root = kernel_root()
    if not root.is_dir():
        return []
    found = [p for p in root.iterdir() if (p / ".complete").exists()]

    def key(p: Path) -> list[int]:
        return [int(x) for x in re.findall(r"\d+", p.name)]

    return sorted(found, key=key, reverse=True)


def kernel_image(kdir: Path) -> Path:
    """The vmlinuz inside an extracted kernel folder."""
    return kdir / "boot" / f"vmlinuz-{kdir.name}"


def current_kernel_package() -> str | None:
    """The versioned kernel package that ``linux-image-amd64`` depends on, or None."""
    res = run_quiet(["apt-cache", "depends", "linux-image-amd64"], timeout_s=60)
    match = re.search(r"Depends:\s*(linux-image-[0-9][\w.+-]*-amd64)\b", res.stdout)
    return match.group(1) if match else None


def missing_apt_commands() -> list[str]:
    """The APT packages whose probe command is not installed."""
    return [pkg for pkg in APT_PACKAGES if which(APT_PROBES[pkg]) is None]


def install_apt() -> bool:
    """apt-get install the missing packages (root only). Returns True when none is missing."""
    missing = missing_apt_commands()
    if not missing:
        log("apt packages: all present")
        return True
    sudo: list[str] = []
    if os.geteuid() != 0:
        if shutil.which("sudo") and run_quiet(["sudo", "-n", "true"], timeout_s=30).returncode == 0:
            sudo = ["sudo", "-n", "env", "DEBIAN_FRONTEND=noninteractive"]
        else:
            log(f"apt packages missing ({' '.join(missing)}), not root and no password-less sudo:")
            log(f"  sudo apt-get install {' '.join(APT_PACKAGES)}")
            return False
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    log(f"apt-get install {' '.join(missing)}")
    subprocess.run(
        [*sudo, "apt-get", "update", "-q"], check=False, env=env, stdin=subprocess.DEVNULL
    )
    res = subprocess.run(
        [*sudo, "apt-get", "install", "-y", "-q", "--no-install-recommends", *missing],
        check=False,
        env=env,
        stdin=subprocess.DEVNULL,
    )
    if res.returncode != 0:
        log(f"apt-get install failed with exit {res.returncode}")
    return not missing_apt_commands()


def install_vng() -> bool:
    """Create the virtme-ng tool venv if missing (no root needed). Returns success."""
    if vng_path() is not None:
        return True
    venv = vng_venv()
    log(f"installing virtme-ng into {venv}")
    shutil.rmtree(venv, ignore_errors=True)
    venv.parent.mkdir(parents=True, exist_ok=True)
    for cmd in (
        [sys.executable, "-m", "venv", str(venv)],
        [str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "virtme-ng"],
    ):
        res = run_quiet(cmd, timeout_s=900)
        if res.returncode != 0:
            log(f"failed: {shlex.join(cmd)}\n{res.stdout[-2000:]}{res.stderr[-2000:]}")
            return False
    return vng_path() is not None


def install_kernel() -> bool:
    """Download and extract the current Debian amd64 kernel if not cached (no root needed).

    Falls back to an already cached kernel when APT cannot name or fetch the current one.
    """
    package = current_kernel_package()
    if package is None:
        if cached_kernels():
            log("apt-cache cannot name the current kernel; using the cached one")
            return True
        log("apt-cache depends linux-image-amd64 names no kernel (run `apt-get update`?)")
        return False
    release = package.removeprefix("linux-image-")
    kdir = kernel_root() / release
    if (kdir / ".complete").exists():
        return True
    log(f"fetching kernel {package} into {kdir}")
    kernel_root().mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=kernel_root(), prefix=".dl-") as tmp:
        # apt-get download writes into the current directory.
        res = subprocess.run(
            ["apt-get", "download", package],
            cwd=tmp,
            capture_output=True,
            text=True,
            check=False,
            stdin=subprocess.DEVNULL,
        )
        debs = list(Path(tmp).glob(f"{package}_*.deb"))
        if res.returncode != 0 or not debs:
            log(f"apt-get download {package} failed: {res.stderr.strip()[-1000:]}")
            return bool(cached_kernels())
        shutil.rmtree(kdir, ignore_errors=True)
        res = run_quiet(["dpkg", "-x", str(debs[0]), str(kdir)], timeout_s=900)
        if res.returncode != 0:
            log(f"dpkg -x failed: {res.stderr.strip()[-1000:]}")
            return bool(cached_kernels())
    if not kernel_image(kdir).exists():
        log(f"no {kernel_image(kdir)} in the package")
        return bool(cached_kernels())
    depmod = which("depmod")
    if depmod is not None:
        run_quiet([depmod, "-a", "-b", str(kdir), release], timeout_s=300)
    (kdir / ".complete").write_text(package + "\n")
    log(f"kernel {release} ready")
    return True


def ensure_vm_tools(apt: bool) -> tuple[bool, str]:
    """Install what is missing for the VM; returns (ready, reason if not).

    Holds a lock on the cache folder so concurrent runs do not install twice at once.
    """
    if platform.machine() not in ("x86_64", "amd64"):
        return False, f"the VM recipe is for x86_64 hosts, this is {platform.machine()}"
    cache_dir().mkdir(parents=True, exist_ok=True)
    with (cache_dir() / ".lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return _ensure_vm_tools_locked(apt)


def _ensure_vm_tools_locked(apt: bool) -> tuple[bool, str]:
    if apt:
        install_apt()
    missing = missing_apt_commands()
    if missing:
        return False, (
            f"missing host packages {' '.join(missing)} "
            f"(install: sudo apt-get install {' '.join(APT_PACKAGES)}, or `make vcan-tools`)"
        )
    if not install_vng():
        return False, f"could not install virtme-ng into {vng_venv()}"
    if not install_kernel() or not cached_kernels():
        return False, f"no Debian kernel cached in {kernel_root()}"
    return True, ""


# --------------------------------------------------------------------------- the VM run


def python_dirs_to_cache() -> list[str]:
    """Host folders the test Python reads at start-up and import (stdlib, site-packages).

    In the guest they are re-mounted through a caching 9p mount: the default uncached
    root mount makes every stat() a round trip through the emulator.
    """
    res = run_quiet(
        [str(REPO / ".venv" / "bin" / "python"), "-c", "import sys; print('\\n'.join(sys.path))"],
        timeout_s=60,
    )
    dirs = sorted(
        {
            os.path.realpath(p)
            for p in res.stdout.splitlines()
            if p and os.path.isdir(p) and os.path.realpath(p) != str(REPO)
        }
    )
    kept: list[str] = []
    for d in dirs:
        if not any(d == k or d.startswith(k + "/") for k in kept):
            kept.append(d)
    # Only bind a python folder that is not a mount point parent of the guest's overlays.
    return [d for d in kept if d.count("/") >= 3]


def vcan_test_files() -> list[str]:
    """The test files holding ``vcan`` tests, from a quick native ``pytest --collect-only``.

    The guest then imports only those files: collecting the whole suite under emulation
    would cost minutes. Returns [] when nothing could be collected (the guest then collects
    everything itself).
    """
    res = run_quiet(
        [
            str(REPO / ".venv" / "bin" / "python"),
            "-m",
            "pytest",
            "--collect-only",
            "-q",
            "-m",
            "vcan",
            "-p",
            "no:cacheprovider",
        ],
        timeout_s=600,
    )
    files: list[str] = []
    for line in res.stdout.splitlines():
        match = re.match(r"^([^\s:]+\.py)::", line)
        if match and match.group(1) not in files:
            files.append(match.group(1))
    return files


def guest_script(outdir: Path, pytest_args: list[str], command: str | None = None) -> str:
    """The bash script the guest runs: vcan0 up, caching mounts, pytest (or `command`, with
    ``$CABLEBOT_VM_OUT`` the host-shared output folder), exit code to a file."""
    env_lines = []
    for key, value in sorted(os.environ.items()):
        if key in ("CI", "PYTEST_ADDOPTS") or key.startswith(("CABLEBOT_", "HYPOTHESIS_")):
            env_lines.append(f"export {key}={shlex.quote(value)}")
    binds = "\n".join(f"bind_cached {shlex.quote(d)}" for d in python_dirs_to_cache())
    py = shlex.quote(str(REPO / ".venv" / "bin" / "python"))
    pytest_cmd = " ".join(
        [
            py,
            "-m",
            "pytest",
            "-m",
            "vcan",
            "-p",
            "no:cacheprovider",
            "--timeout=900",
            "--durations=5",
            *(shlex.quote(a) for a in pytest_args),
        ]
    )
    if command is not None:
        pytest_cmd = command
    elif not any(a.endswith(".py") or "::" in a or os.path.isdir(a) for a in pytest_args):
        files = vcan_test_files()
        log(f"vcan test files: {' '.join(files) if files else '(none found: all of tests/)'}")
        pytest_cmd += "".join(f" {shlex.quote(f)}" for f in files)
    out = shlex.quote(str(outdir))
    return f"""#!/bin/bash
exec > {out}/guest.log 2>&1
set -u
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
{chr(10).join(env_lines)}
export CABLEBOT_UNDER_VM=1
export CABLEBOT_VM_OUT={out}
echo "guest: kernel $(uname -r), $(nproc) CPU(s)"
if ! modprobe -a {" ".join(CAN_MODULES)}; then
    echo "guest: modprobe failed"
fi
if ! (ip link add dev {VCAN} type vcan && ip link set up {VCAN}); then
    echo "guest: could not create {VCAN}"; echo 3 > {out}/rc; exit 3
fi
ip -brief link show {VCAN}
# A second, caching 9p mount of the host root for the Python trees (read-only, and the
# host does not change them during the run).
bind_cached() {{
    [ -d "/run/croot$1" ] && mount --bind "/run/croot$1" "$1" || echo "guest: no cache for $1"
}}
mkdir -p /run/croot
if mount -t 9p -o ro,trans=virtio,version=9p2000.L,cache=loose,msize=512000,access=any \\
        cablebot_croot /run/croot; then
{binds}
else
    echo "guest: no caching mount; Python will be slower"
fi
cd {shlex.quote(str(REPO))}
echo "guest: booted; running {"the command" if command is not None else "pytest -m vcan"}"
{pytest_cmd}
echo $? > {out}/rc.tmp && mv {out}/rc.tmp {out}/rc
"""


class Tail(threading.Thread):
    """Copy a growing file to stdout until stopped; notes when the file first appears."""

    def __init__(self, path: Path) -> None:
        super().__init__(daemon=True)
        self.path = path
        self.stop_event = threading.Event()
        self.appeared_at: float | None = None

    def run(self) -> None:
        handle = None
        try:
            while True:
                stopping = self.stop_event.is_set()
                if handle is None and self.path.exists():
                    handle = self.path.open("rb")
                    self.appeared_at = time.monotonic()
                if handle is not None:
                    chunk = handle.read()
                    if chunk:
                        sys.stdout.buffer.write(chunk)
                        sys.stdout.flush()
                if stopping:
                    return
                self.stop_event.wait(0.3)
        finally:
            if handle is not None:
                handle.close()


def _exit_on_signal(signum: int, _frame: object) -> None:
    """Turn SIGTERM/SIGHUP into SystemExit so ``finally`` blocks kill the VM."""
    sys.exit(128 + signum)


def run_in_vm(
    pytest_args: list[str], command: str | None = None, keep: tuple[str, ...] = ()
) -> int:
    """Boot the VM, run the vcan suite (or the shell `command`) in it, stream its output;
    returns pytest's (the command's) exit code. Files named in `keep` that the guest wrote
    into ``$CABLEBOT_VM_OUT`` are copied to the top of the checkout."""
    vng = vng_path()
    kdir = cached_kernels()[0]
    cpus = os.environ.get("CABLEBOT_VCAN_CPUS", "2")
    memory = os.environ.get("CABLEBOT_VCAN_MEMORY", "2G")
    timeout_s = float(os.environ.get("CABLEBOT_VCAN_TIMEOUT_S", "2400"))
    kvm = os.environ.get("CABLEBOT_VCAN_KVM", "") == "1"
    assert vng is not None
    outdir = Path(tempfile.mkdtemp(prefix="cablebot-vcan-"))
    script = outdir / "guest.sh"
    script.write_text(guest_script(outdir, pytest_args, command))
    print(
        f"vcan suite: running inside virtme-ng VM (kernel {kdir.name}, {cpus} CPUs, {memory}, "
        f"{'KVM' if kvm else 'TCG emulation, no KVM'})",
        flush=True,
    )
    log(f"guest output and exit code in {outdir}")
    cmd = [
        str(vng),
        "--run",
        str(kernel_image(kdir)),
        "--user",
        "root",
        "--memory",
        memory,
        "--cpus",
        cpus,
        # The guest picks hpet otherwise: every time.monotonic() then costs ~8 us (2.7x more).
        "--append=tsc=reliable",
        "--append=clocksource=tsc",
        "--rwdir",
        str(outdir),
        "--overlay-rwdir",
        str(REPO),
        "--qemu-opts=-fsdev local,id=cablebot_croot,path=/,security_model=none,readonly=on,"
        "multidevs=remap -device virtio-9p-pci,fsdev=cablebot_croot,mount_tag=cablebot_croot",
    ]
    if not kvm:
        cmd.append("--disable-kvm")
    cmd += ["--", f"bash {shlex.quote(str(script))}"]
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(vng_venv() / "bin"), *SBIN_PATHS, env.get("PATH", "")])
    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, _exit_on_signal)
    tail = Tail(outdir / "guest.log")
    tail.start()
    t0 = time.monotonic()
    with (outdir / "vng.log").open("wb") as vng_log:
        proc = subprocess.Popen(
            cmd,
            cwd=REPO,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=vng_log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            vng_rc = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            log(f"VM still running after {timeout_s:.0f} s: killing it")
            vng_rc = -1
        finally:
            # Also on Ctrl-C / SIGTERM: never leave a qemu behind (it has its own session).
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    elapsed_s = time.monotonic() - t0
    tail.stop_event.set()
    tail.join(timeout=10)
    rc_file = outdir / "rc"
    boot_s = (tail.appeared_at - t0) if tail.appeared_at is not None else float("nan")
    if not rc_file.exists():
        log(f"the guest wrote no exit code (vng exit {vng_rc}); vng output:")
        sys.stdout.write((outdir / "vng.log").read_text(errors="replace")[-4000:])
        return 1
    rc = int(rc_file.read_text().strip() or "1")
    for name in keep:
        if (outdir / name).exists():
            shutil.copyfile(outdir / name, REPO / name)
            log(f"wrote {REPO / name}")
    log(f"VM: boot {boot_s:.1f} s, whole run {elapsed_s:.1f} s, guest pytest exit {rc}")
    if rc == 0:
        shutil.rmtree(outdir, ignore_errors=True)
    else:
        log(f"kept for inspection: {outdir}/guest.log")
    return rc


# --------------------------------------------------------------------------- commands


def cmd_tools(apt: bool) -> int:
    """``tools``: install everything the VM needs. Returns 0 when ready."""
    ready, reason = ensure_vm_tools(apt=apt)
    if ready:
        log(f"VM tools ready: {vng_path()}, kernel {cached_kernels()[0].name}")
        return 0
    log(f"VM tools NOT ready: {reason}")
    return 1


def skip(reason: str) -> int:
    """Print the SKIPPED banner; exit status 1 under CI, else 0."""
    lines = [
        "vcan suite SKIPPED: the SocketCAN tests (pytest -m vcan) did NOT run.",
        f"reason: {reason}",
        "to run them natively:  sudo modprobe vcan && sudo ip link add dev vcan0 type vcan"
        " && sudo ip link set up vcan0",
        "to run them in a VM:   make vcan-tools   (qemu, virtme-ng, a Debian kernel)",
    ]
    if is_ci():
        lines.append("CI=true: a skipped vcan suite is a FAILURE.")
    banner(lines)
    return 1 if is_ci() else 0


def cmd_test(pytest_args: list[str]) -> int:
    """``test``: run the vcan suite natively, in the VM, or skip loudly. Returns the exit code."""
    mode = os.environ.get("CABLEBOT_VCAN_MODE", "auto")
    if mode == "skip":
        return skip("CABLEBOT_VCAN_MODE=skip")
    if mode in ("auto", "native"):
        ok, reason = try_create_native_vcan()
        if ok:
            print(f"vcan suite: running natively on this kernel ({platform.release()})")
            cmd = [str(REPO / ".venv" / "bin" / "python"), "-m", "pytest", "-m", "vcan"]
            return subprocess.call([*cmd, *pytest_args], cwd=REPO)
        if mode == "native":
            return skip(f"CABLEBOT_VCAN_MODE=native but {reason}")
        log(f"native vcan unavailable: {reason}; trying the VM")
    # Under CI a skip fails anyway, so install the host packages too (as root / sudo -n).
    ready, why = ensure_vm_tools(apt=is_ci())
    if not ready:
        return skip(f"no native vcan, and no VM: {why}")
    return run_in_vm(pytest_args)


BENCH_OUT = "bench-vcan.json"


def cmd_bench(bench_args: list[str]) -> int:
    """``bench``: the SocketCAN I/O benchmark (`controller.cli.bench_vcan`) natively or in the
    VM; writes ``bench-vcan.json`` at the top of the checkout. Returns its exit code."""
    py = str(REPO / ".venv" / "bin" / "python")
    mode = os.environ.get("CABLEBOT_VCAN_MODE", "auto")
    if mode in ("auto", "native"):
        ok, reason = try_create_native_vcan()
        if ok:
            cmd = [py, "-m", "controller.cli.bench_vcan", "--out", str(REPO / BENCH_OUT)]
            return subprocess.call([*cmd, *bench_args], cwd=REPO)
        log(f"native vcan unavailable: {reason}; trying the VM")
    ready, why = ensure_vm_tools(apt=is_ci())
    if not ready:
        log(f"bench-vcan cannot run: no native vcan, and no VM: {why}")
        return 1
    command = " ".join(
        [
            shlex.quote(py),
            "-m",
            "controller.cli.bench_vcan",
            "--out",
            f'"$CABLEBOT_VM_OUT"/{BENCH_OUT}',
            *(shlex.quote(a) for a in bench_args),
        ]
    )
    return run_in_vm([], command=command, keep=(BENCH_OUT,))


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and run a sub-command; returns the process exit status."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p_tools = sub.add_parser("tools", help="install the VM tools (idempotent)")
    p_tools.add_argument("--apt", action="store_true", help="also apt-get install (as root)")
    p_test = sub.add_parser("test", help="run pytest -m vcan natively or in the VM")
    p_test.add_argument("pytest_args", nargs=argparse.REMAINDER)
    p_bench = sub.add_parser("bench", help="the SocketCAN I/O benchmark, natively or in the VM")
    p_bench.add_argument("bench_args", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    if args.command == "bench":
        return cmd_bench(list(args.bench_args))
    if args.command == "tools":
        return cmd_tools(apt=args.apt)
    return cmd_test(list(args.pytest_args))


if __name__ == "__main__":
    sys.exit(main())
