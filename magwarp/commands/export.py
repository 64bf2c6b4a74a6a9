"""``magwarp export``: write a trained policy as ONNX (for industrial runtimes, e.g. Beckhoff TwinCAT's ML runtime).

    magwarp export runs/b0_ppo/policy.pt --onnx b0.onnx
    magwarp export runs/pushbox --onnx pushbox.onnx        # a run folder means its policy.pt
    magwarp export pretrained:b0_ppo --onnx b0.onnx        # a policy shipped with magwarp
    magwarp export pretrained:b0_ppo --onnx b0.onnx --target twincat   # + b0.onnx.json (docs/twincat.md)

The ONNX graph takes ``obs`` float32 [batch, obs_dim] (the goal-dict observation flattened in sorted key order:
achieved_goal, desired_goal, observation) and returns ``action`` float32 [batch, action_dim] in the env's units
(normalisation and action scaling inside). After writing, onnxruntime (when installed) is checked against torch on random inputs.
Needs the optional packages onnx and onnxruntime (pip install 'magwarp[onnx]').

--target twincat: for an embedded runtime (TwinCAT's ML runtime on a PLC task): the deterministic action only, a fixed
batch of 1 (obs [1, obs_dim] -> action [1, action_dim]), static shapes, only the operators of a documented allow-list
(checked: a graph with any other is refused), and metadata (observation layout, action units and scaling, control
cycles per action and cycle time, env id and options, magwarp version) in the ONNX metadata_props and in the JSON
sidecar OUT.json. --target twincat-mlp: only the operators Beckhoff documents for its real-time runtime's MLPs (Gemm
and activations): the normaliser folded into the first layer; the observation clip, a clip squashing and the action
scale are left to the PLC (the metadata gives them). See magwarp.training.twincat and docs/twincat.md.
"""

from __future__ import annotations

import argparse
import math
import os

from magwarp.commands import CommandError, UsageError, add_trust_option, loading_errors

HELP = "export a trained policy as ONNX"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("export", help=HELP, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policy", metavar="POLICY",
                   help="policy.pt (TorchScript or torch.save'd module), a run folder, or pretrained:NAME")
    p.add_argument("--onnx", required=True, metavar="OUT", help="the .onnx file to write")
    p.add_argument("--target", default="onnx", choices=("onnx", "twincat", "twincat-mlp"),
                   help="onnx: the policy's flat path, dynamic batch (default); twincat: batch 1, checked operator "
                        "set, metadata and OUT.json sidecar; twincat-mlp: the same with Gemm and activations only")
    p.add_argument("--opset", type=int, default=17, help="ONNX opset (default 17)")
    p.add_argument("--obs-dim", type=int, default=None, help="observation size, for modules that do not record it")
    p.add_argument("--atol", type=float, default=1e-5,
                   help="largest accepted |onnxruntime - torch| as a fraction of the action range (default 1e-5)")
    p.add_argument("--no-check", action="store_true", help="skip the onnxruntime comparison")
    add_trust_option(p)
    return p


def run(args) -> int:
    from magwarp.training.pretrained import resolve_policy

    args.policy = resolve_policy(args.policy)
    if not os.path.exists(args.policy):
        raise UsageError(f"no policy at {args.policy!r}")
    if os.path.isdir(args.policy) and not os.path.isfile(os.path.join(args.policy, "policy.pt")):
        raise UsageError(f"{args.policy!r} is a folder without a policy.pt")
    if not (math.isfinite(args.atol) and args.atol > 0):
        raise UsageError(f"--atol must be a positive number, got {args.atol}")
    if os.path.isdir(args.onnx):
        raise UsageError(f"--onnx {args.onnx!r} is a folder; give a file name")
    plc = args.target != "onnx"
    if plc and args.obs_dim is not None:
        raise UsageError(f"--obs-dim is not used with --target {args.target} "
                         "(the policy and its env give the observation size)")
    from magwarp.training.export import export_onnx

    if plc:  # it builds the policy's env (one world, CPU) to describe it
        import warp as wp

        wp.config.quiet = True  # Warp < 1.19
        wp.config.log_level = getattr(wp, "LOG_WARNING", 30)  # no init banner or module-load lines

    with loading_errors():
        try:
            info = export_onnx(args.policy, args.onnx, opset=args.opset, obs_dim=args.obs_dim, check=not args.no_check,
                               atol=args.atol, trusted=args.trust, target=args.target)
        except RuntimeError as e:
            raise CommandError(str(e)) from None
        except ValueError as e:
            if not plc:
                raise
            raise UsageError(str(e)) from None  # the policy does not fit the target (operators, env, sizes)
    diff = info["max_diff"]
    check = ("not checked (onnxruntime missing)" if diff is None and not args.no_check else
             "not checked" if diff is None else
             f"onnxruntime matches torch (max diff {diff:.2g} of the action range, {info['max_abs_diff']:.2g} in the "
             f"env's units)")
    batch = "1" if plc else "batch"
    print(f"wrote {args.onnx}: obs [{batch}, {info['obs_dim']}] -> action [{batch}, {info['action_dim']}]; {check}")
    if plc:
        meta = info["metadata"]
        control, action = meta["control"], meta["action"]
        print(f"operators: {', '.join(info['operators'])}; metadata: {info['sidecar']} and the ONNX metadata_props "
              f"(one action every {control['num_cycles']} cycles of {control['cycle_time_s'] * 1e3:g} ms, "
              f"{action['quantity']} in {action['components'][0]['unit']})")
        if not action["scale_in_graph"]:
            squash = "" if action["squash_in_graph"] else "clip the output to [-1, 1], "
            print(f"the PLC's part: clip obs to obs_normalization.raw_low/raw_high before the call; after it, {squash}"
                  f"multiply by action.scale")
    return 0
