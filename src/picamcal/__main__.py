"""``python3 -m picamcal``: the ``picamcal`` command, where the script is not on the PATH."""

from .cli import main

if __name__ == "__main__":
    main()
