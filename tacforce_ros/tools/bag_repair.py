"""bag_repair: make bags cut off by a crash (a recorder killed, a power cut) whole again.

    bag_repair BAG [BAG ...]

Each MCAP file that does not end properly is rewritten with every complete chunk it holds (what
the recorder wrote up to its last flush, `flush_seconds`); an empty one is removed; metadata.yaml
is rebuilt from the files. Complete files are only read. Prints what each file kept and dropped.
Exit code 0 when every bag is whole afterwards, 2 for a folder that is not a bag of MCAP files.
(recording/bag_repair.py has the rules.)
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tacforce_ros.bagio import BagError
from tacforce_ros.recording.bag_repair import repair_bag


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog='bag_repair', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('bags', nargs='+', type=Path, help='bag folders')
    args = parser.parse_args(argv)
    code = 0
    for bag in args.bags:
        try:
            report = repair_bag(bag)
        except (BagError, OSError) as exc:
            print(f'{bag}: {exc}', file=sys.stderr)
            code = 2
            continue
        for f in report.files:
            if f.recovered:
                print(f'{bag}/{f.path}: cut off; kept {f.messages} messages in complete chunks, '
                      f'dropped the last {f.bytes_dropped} bytes ({f.stopped_by})')
            else:
                print(f'{bag}/{f.path}: complete, {f.messages} messages')
        for name in report.removed:
            print(f'{bag}/{name}: no complete message; removed')
        print(f'{bag}: {"repaired" if report.repaired else "already whole"}; metadata.yaml '
              'rebuilt')
    sys.exit(code)


if __name__ == '__main__':
    main()
