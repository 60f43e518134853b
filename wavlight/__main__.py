"""``python -m wavlight``: the command line, the same as the ``wavlight`` command."""
from wavlight.cli.main import main

if __name__ == "__main__":
    main()
