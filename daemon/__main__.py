from daemon.cli import script

script()
