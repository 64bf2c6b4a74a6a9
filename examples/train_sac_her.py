"""SAC + hindsight experience replay on a batched magwarp env: the algorithm is :mod:`magwarp.training.sac_her`
(one CleanRL-style module, read it top to bottom); this script only runs it, with the same options.

    python examples/train_sac_her.py --env-id magwarp/PushBox-v0 --device cuda --minutes 15 --out runs/pushbox_sac
    python examples/train_sac_her.py --resume runs/pushbox_sac --minutes 5
    python -m magwarp.training.sac_her --help                           # the same module, installed
    magwarp train magwarp/PushBox-v0 --algo sac-her --minutes 15
"""

import sys

from magwarp.training.sac_her import main

if __name__ == "__main__":
    sys.exit(main())
