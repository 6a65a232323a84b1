"""`python -m controller.cli`: the `cablebot` command."""

from controller.cli import main

raise SystemExit(main())
