"""Run a ``springtrack`` or ``firmware-sim`` command line in this process and report its
peak resident memory: ``python tests/support/peak_rss.py LIMIT_MIB springtrack track IN --model M
...`` prints ``peak_rss_mib N`` as the last line of stderr and exits with the command's
status.  The process may not allocate more than LIMIT_MIB of data (RLIMIT_DATA), so that
memory growing with the input's time span fails at once (MemoryError) instead of
exhausting the machine.  Used by tests/test_springtrack/test_memory.py."""
import resource
import sys


def main() -> int:
    limit = int(sys.argv[1]) << 20
    resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))
    tool, argv = sys.argv[2], sys.argv[3:]
    if tool == "springtrack":
        from springtrack.cli import main as run
    else:
        from firmware_sim.cli import main as run
    try:
        rc = run(argv)
    except MemoryError:
        rc = 99
    finally:
        print(f"peak_rss_mib {peak_mib():.1f}", file=sys.stderr)
    return rc


def peak_mib() -> float:
    """This process's peak resident memory since it started (Linux VmHWM: ru_maxrss would
    carry the forking parent's over the exec)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


if __name__ == "__main__":
    sys.exit(main())
