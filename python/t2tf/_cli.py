"""The `t2tf` command the wheel installs: the Rust command line, run in this process."""
import sys

from ._t2tf import cli_main


def main() -> int:
    """Run `t2tf` on this process's arguments; returns its exit status."""
    return cli_main(sys.argv)


if __name__ == "__main__":
    sys.exit(main())
