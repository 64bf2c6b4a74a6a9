"""PPO on a batched magwarp env: the algorithm is :mod:`magwarp.training.ppo` (one CleanRL-style module, read it
top to bottom); this script only runs it, with the same options.

    python examples/train_ppo.py --env-id magwarp/TrajectoryPlanningB0-v0 --device cuda --minutes 15 --out runs/b0_ppo
    python examples/train_ppo.py --resume runs/b0_ppo --minutes 5      # continue the same run
    python -m magwarp.training.ppo --help                               # the same module, installed
    magwarp train magwarp/TrajectoryPlanningB0-v0 --algo ppo --minutes 15
"""

import sys

from magwarp.training.ppo import main

if __name__ == "__main__":
    sys.exit(main())
