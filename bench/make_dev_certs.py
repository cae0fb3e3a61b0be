"""Make a dev CA + robot/client certificates for the zenoh body link (bench and tests).

    .venv/bin/python bench/make_dev_certs.py OUT_DIR [--robot-san IP:192.168.50.5] [--client capm-commander]

See `sim_bench/dev_pki.py` (the code) and docs/security.md (provisioning, rotation).
"""

import sys

from sim_bench.dev_pki import main

if __name__ == "__main__":
    sys.exit(main())
