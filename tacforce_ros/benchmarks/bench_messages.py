"""bench_messages: what the estimator's serialized fast path saves per tactile frame.

Times one frame's intake (serialized /tactile/raw -> counts) and output (18 WrenchStamped and
one ForceEstimateArray -> bytes to publish), once through rclpy message objects and once through
nodes/serialized.py, the two ways alternating in blocks (nodes/serialization_cost.py). Prints a
table of per-frame medians and p99s with their ratios; writes JSON (--out).
"""
from __future__ import annotations

import argparse
import json
import platform

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.serialization_cost import intake_cost, output_cost
from tacforce_ros.paths import output_file


def table(result: dict) -> str:
    lines = ['| part | way | median us | p99 us |', '|---|---|---|---|']
    for part in ('intake', 'output'):
        for way, t in result[part].items():
            lines.append(f'| {part} | {way} | {t["median_us"]:.1f} | {t["p99_us"]:.1f} |')
    for part in ('intake', 'output'):
        lines.append(f'\n{part}: message objects / serialized = '
                     f'{result["ratio_median"][part]:.1f}x (median)')
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--frames', type=int, default=2000, help='frames timed per way')
    parser.add_argument('--out', type=output_file, help='write the results as JSON here')
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error('--frames must be >= 1')
    hand = load_hand()
    result = {'frames': args.frames, 'taxels': hand.n_taxels, 'arrays': len(hand.arrays),
              'python': platform.python_version(),
              'intake': intake_cost(hand, args.frames), 'output': output_cost(hand, args.frames)}
    result['ratio_median'] = {
        part: result[part]['message objects']['median_us'] / result[part]['serialized']['median_us']
        for part in ('intake', 'output')}
    print(table(result))
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=2))
        print(f'wrote {args.out}')


if __name__ == '__main__':
    main()
