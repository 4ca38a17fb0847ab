"""Run the pmba command line: ``python -m pmba_ros VERB ...``."""

from pmba_ros.cli.main import main

if __name__ == '__main__':
    raise SystemExit(main())
