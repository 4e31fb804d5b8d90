"""``python -m headsim`` runs the command line."""

from headsim.cli import main

if __name__ == "__main__":
    main()
