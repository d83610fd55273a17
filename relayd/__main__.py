import sys

try:
    from relayd.cli import main

    code = main()
except KeyboardInterrupt:  # Ctrl-C while the command line itself is still being imported
    code = 130
sys.exit(code)
