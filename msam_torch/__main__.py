import sys

from msam_torch.cli.main import main

sys.exit(main())
