import sys

from mapfilter.cli import main

sys.exit(main())
