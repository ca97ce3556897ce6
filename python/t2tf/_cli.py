"""The `t2tf` command the wheel installs: the Rust command line, run in this process."""
import sys

from ._t2tf import cli_main


def main() -> int:
    """Run `t2tf` on this process's arguments; returns its exit status. The program is named
    `t2tf` in its messages however it was started (`python -m t2tf` has `__main__.py`)."""
    return cli_main(["t2tf"] + sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())
