"""Measured results as files: what a command measured as JSON, and a Markdown table generated from
it, both naming the code's commit, the machine and its load, so a figure is never typed by hand."""
from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from pathlib import Path
from typing import Any, Callable

REPOSITORY = Path(__file__).resolve().parent.parent


def commit() -> str:
    """`git describe --always --dirty` of the checkout (a commit, '-dirty' when tracked files
    differ from it); outside a git checkout, the installed package's version."""
    try:
        return subprocess.run(['git', 'describe', '--always', '--dirty'], cwd=REPOSITORY,
                              capture_output=True, text=True, timeout=10,
                              check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        from importlib.metadata import PackageNotFoundError, version
        try:
            return version('tacforce_ros')
        except PackageNotFoundError:
            return 'unknown'


def cpu_model() -> str:
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance() -> dict[str, Any]:
    """Where and when a measurement ran: commit, date, machine, and the load average before."""
    return {'commit': commit(), 'date': time.strftime('%Y-%m-%d %H:%M:%S %z'),
            'machine': f'{os.cpu_count()} x {cpu_model()}, {platform.system()} '
                       f'{platform.release()}, Python {platform.python_version()}',
            'load_before': [round(x, 2) for x in os.getloadavg()]}


def header(result: dict[str, Any], title: str, command: str) -> str:
    """The Markdown lines that open a results table: what ran, on which code and machine."""
    where = result['provenance']
    after = where.get('load_after')
    return (f'# {title}\n\n`{command}`, code {where["commit"]}, {where["date"]}; '
            f'{where["machine"]}; load average (1/5/15 min) before '
            f'{"/".join(f"{x:g}" for x in where["load_before"])}'
            + (f', after {"/".join(f"{x:g}" for x in after)}' if after else '') + '.\n')


def write(out: Path, name: str, result: dict[str, Any],
          markdown: Callable[[dict[str, Any]], str]) -> tuple[Path, Path]:
    """<out>/<name>.json and <out>/<name>.md, the table made by `markdown(result)` once the load
    average after the measurement is in the result."""
    result['provenance']['load_after'] = [round(x, 2) for x in os.getloadavg()]
    out.mkdir(parents=True, exist_ok=True)
    json_path, md_path = out / f'{name}.json', out / f'{name}.md'
    json_path.write_text(json.dumps(result, indent=2) + '\n')
    md_path.write_text(markdown(result))
    return json_path, md_path
