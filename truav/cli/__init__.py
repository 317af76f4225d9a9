"""The command line: every argparse parser of TRUAV and nothing else (the `truav` program in
:mod:`truav.cli.main`, `truav-swarm` in :mod:`truav.cli.swarm`, `truav log` in :mod:`truav.cli.log`).
No module outside this package imports it."""
