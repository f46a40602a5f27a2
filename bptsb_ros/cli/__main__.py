import sys

from bptsb_ros.cli import main

sys.exit(main())
