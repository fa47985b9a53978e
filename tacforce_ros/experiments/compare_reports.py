"""compare_reports: did a change move the main job's tables? Two `reproduce` reports compared
figure by figure.

    compare_reports BEFORE/report.json AFTER/report.json --out docs/results/compare

Every number of the two report.json files is paired by where it sits (a list of rows by the
row's own names: object and controller, model and cut-off, test plate). The figures a run
computes from its seeds (Table I-III, the whole hand, the low-passed loop, the filters' group
delay) must be equal; what a run measures on the machine (times, latencies, load, the node
graph's run over DDS) is listed apart and never judged. Writes <out>/compare.json and
<out>/compare.md; exits 1 when a computed figure differs by more than --tolerance.

The networks' training (M4, M5) repeats to the bit for its seeds on one kind of processor, but
torch's CPU kernels differ between processor models (vector widths, and so the order of float
sums), which moves those models' figures by up to a few mN. --trained-tolerance judges the
figures that name M4 or M5 against a tolerance of their own, for reports from two machines.
"""
from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import Any, Iterator

from tacforce_ros.results import header, provenance, write

# What a run measures rather than computes: its time, its machine, the node graph over DDS.
MEASURED = re.compile(r'(^|/)(run|node_path|node_latency|timing_us|figures|paths|label'
                      r'|work_dir)(/|$)|seconds|(?<!group_delay)_ms(/|$)|_us(/|$)|load|date')
# Figures of the torch-trained models: their rows, and the targets that name them.
TRAINED = re.compile(r'\bM[45]\b')
# Names that identify a row in a list of rows, in the order tried.
ROW_KEYS = ('object', 'controller', 'model', 'cutoff_hz', 'test_plate', 'array', 'target')


def _row_name(row: dict, index: int) -> str:
    named = [f'{key}={row[key]}' for key in ROW_KEYS if key in row]
    return ','.join(named) if named else str(index)


def leaves(value: Any, path: str = '') -> Iterator[tuple[str, Any]]:
    """(path, value) of every number, string, bool or None in `value`."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from leaves(item, f'{path}/{key}' if path else str(key))
    elif isinstance(value, list):
        names = [str(index) for index in range(len(value))]
        if value and all(isinstance(item, dict) for item in value):
            named = [_row_name(item, index) for index, item in enumerate(value)]
            names = named if len(set(named)) == len(named) else names   # a name twice: by place
        for name, item in zip(names, value):
            yield from leaves(item, f'{path}[{name}]')
    else:
        yield path, value


def _difference(before: Any, after: Any) -> float | None:
    """|after - before| for two numbers (0 for two NaNs), None when either is not a number."""
    numbers = (int, float)
    if isinstance(before, bool) or isinstance(after, bool) \
            or not isinstance(before, numbers) or not isinstance(after, numbers):
        return None
    if math.isnan(before) and math.isnan(after):
        return 0.0
    return abs(float(after) - float(before))


def compare(before: dict, after: dict, tolerance: float = 0.0,
            trained_tolerance: float | None = None) -> dict[str, Any]:
    """The figures of two reports paired by path: computed ones that differ (over `tolerance`;
    the trained models' figures, TRAINED, over `trained_tolerance` where given), the count of
    equal ones (and of those equal only within `trained_tolerance`), those only one report
    has, and how many measured figures and texts (labels, explanations) were set aside."""
    old, new = dict(leaves(before)), dict(leaves(after))
    differ, equal, measured, text, trained_within = [], 0, 0, 0, 0
    for path in sorted(old.keys() & new.keys()):
        a, b = old[path], new[path]
        if MEASURED.search(path):
            measured += 1
            continue
        if isinstance(a, str) and isinstance(b, str):     # labels and explanations, not figures
            text += 1
            continue
        delta = _difference(a, b)
        trained = trained_tolerance is not None and TRAINED.search(path) is not None
        if delta is None:
            same = a == b
        else:
            same = delta <= (max(tolerance, trained_tolerance) if trained else tolerance)
            trained_within += same and trained and delta > tolerance
        if same:
            equal += 1
        else:
            differ.append({'figure': path, 'before': a, 'after': b, 'difference': delta})
    only = {'before': sorted(p for p in old.keys() - new.keys() if not MEASURED.search(p)),
            'after': sorted(p for p in new.keys() - old.keys() if not MEASURED.search(p))}
    return {'tolerance': tolerance, 'trained_tolerance': trained_tolerance, 'equal': equal,
            'equal_within_trained_tolerance': trained_within, 'differ': differ, 'only': only,
            'measured_set_aside': measured, 'text_set_aside': text}


def markdown(result: dict[str, Any]) -> str:
    c = result['comparison']
    lines = [header(result, 'The main job before and after', result['command']), '',
             f'Reports: before `{result["before"]["path"]}` (code {result["before"]["code"]}, '
             f'skin {result["before"]["skin"]}), after `{result["after"]["path"]}` (code '
             f'{result["after"]["code"]}, skin {result["after"]["skin"]}).', '',
             f'Computed figures equal (within {c["tolerance"]:g}): **{c["equal"]}**; differing: '
             f'**{len(c["differ"])}**; measured on the machine (times, load, the node graph), '
             f'not compared: {c["measured_set_aside"]}; texts not compared: '
             f'{c["text_set_aside"]}; only before: {len(c["only"]["before"])}; only after: '
             f'{len(c["only"]["after"])}.', '']
    if c.get('trained_tolerance') is not None:
        lines += [f'Figures of M4 and M5 judged within {c["trained_tolerance"]:g} (trained on '
                  f'another processor model, torch\'s kernels sum in another order): '
                  f'{c["equal_within_trained_tolerance"]} equal only within it.', '']
    if c['differ']:
        lines += ['| figure | before | after | difference |', '|---|---|---|---|']
        lines += [f'| `{d["figure"]}` | {d["before"]} | {d["after"]} | '
                  f'{"-" if d["difference"] is None else format(d["difference"], ".3g")} |'
                  for d in c['differ']]
        lines.append('')
    for side in ('before', 'after'):
        if c['only'][side]:
            lines += [f'Only {side}: ' + ', '.join(f'`{p}`' for p in c['only'][side]), '']
    return '\n'.join(lines)


def _about(path: Path, report: dict) -> dict[str, Any]:
    return {'path': str(path), 'code': report.get('run', {}).get('code_version', 'unknown'),
            'skin': report.get('skin', report.get('settings', {}).get('skin', 'empirical'))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='compare_reports', description=__doc__.split('\n')[0])
    parser.add_argument('before', type=Path, help="the first run's report.json")
    parser.add_argument('after', type=Path, help="the second run's report.json")
    parser.add_argument('--out', type=Path, required=True,
                        help='folder for compare.json and compare.md')
    parser.add_argument('--tolerance', type=float, default=0.0,
                        help='largest absolute difference counted as equal (default 0: equal)')
    parser.add_argument('--trained-tolerance', type=float, default=None,
                        help='largest absolute difference counted as equal in the figures of '
                             'M4 and M5 (trained with torch) alone: for reports of two '
                             'processor models (default: --tolerance)')
    args = parser.parse_args(argv)
    for name in ('tolerance', 'trained_tolerance'):
        value = getattr(args, name)
        if value is not None and not (value >= 0.0 and math.isfinite(value)):
            parser.error(f'--{name.replace("_", "-")} {value}: a finite number >= 0')
    reports = {}
    for side in ('before', 'after'):
        path = getattr(args, side)
        try:
            reports[side] = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            parser.error(f'{side} report {path}: {exc}')
        if not isinstance(reports[side], dict) or 'table_I' not in reports[side]:
            parser.error(f'{side} report {path}: not a reproduce report.json (no table_I)')
    result = {'provenance': provenance(),
              'command': 'compare_reports ' + ' '.join(argv if argv is not None else sys.argv[1:]),
              'before': _about(args.before, reports['before']),
              'after': _about(args.after, reports['after']),
              'comparison': compare(reports['before'], reports['after'], args.tolerance,
                                    args.trained_tolerance)}
    json_path, md_path = write(args.out, 'compare', result, markdown)
    c = result['comparison']
    print(f'{c["equal"]} computed figures equal, {len(c["differ"])} differ '
          f'({c["measured_set_aside"]} measured ones set aside): {md_path}')
    return 1 if c['differ'] else 0


if __name__ == '__main__':
    sys.exit(main())
