import sys

from awiwi_drake.cli import main

sys.exit(main())
