#!/usr/bin/env bash
# Install this checkout with no registry (the lent GPU machines have numpy, numba, numba-cuda, h5py
# and scipy, but no network), compile the kernels the table needs, and run docs/device.py.
#   bash docs/device.sh OUT_FOLDER
set -euo pipefail
out=${1:-.}
site=/tmp/granlab-site
python3 -m pip install -q --no-deps --no-build-isolation --ignore-requires-python --no-compile --target "$site" .
export PYTHONPATH=$site PYTHONUNBUFFERED=1
python3 -c "import granlab.app.commands as c; c.main(['compile', '--only', 'step-pieces', 'step-cundall-strack', 'state', 'step-pieces-threads', 'step-cundall-strack-threads'])" 2>&1 | tail -2
python3 docs/device.py --out "$out/device.json"
