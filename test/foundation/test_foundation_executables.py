"""Every executable the README lists is installed, answers --help, and is one the package
declares: the README's list, setup.py's entry points and the installed files agree."""
import re
import subprocess
from pathlib import Path

import pytest

from ros_processes import executable

REPO = Path(__file__).resolve().parents[2]
# The README's lists of nodes and tools: bullets that start with backticked executables.
LISTED = re.compile(r'^\* ((?:`[a-z_]+`(?:, )?)+):', re.M)


def readme_executables() -> list[str]:
    text = (REPO / 'README.md').read_text()
    section = text[text.index('## The executables'):text.index('## Faults')]
    names = []
    for match in LISTED.finditer(section):
        names += re.findall(r'`([a-z_]+)`', match.group(1))
    return names


def declared_executables() -> set[str]:
    text = (REPO / 'setup.py').read_text()
    nodes = re.search(r'NODES = \[(.*?)\]', text, re.S).group(1)
    tools = re.search(r'TOOLS = \{(.*?)\n\}', text, re.S).group(1)
    return set(re.findall(r"'([a-z_]+)'", nodes)) | set(re.findall(r"^\s+'([a-z_]+)':", tools,
                                                                        re.M))


def test_the_readme_lists_every_declared_executable_and_only_those():
    listed = readme_executables()
    assert len(listed) == len(set(listed)), listed
    assert set(listed) == declared_executables()


def test_every_listed_executable_answers_help():
    names = readme_executables()
    # Started together: the import of each takes a second or two, most of it waiting on disk.
    procs = {name: subprocess.Popen([str(executable(name)), '--help'], stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True) for name in names}
    failed = {}
    for name, proc in procs.items():
        try:
            out, _ = proc.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
        if proc.returncode != 0 or 'usage' not in out:
            failed[name] = (proc.returncode, out[-500:])
    assert not failed, failed


@pytest.mark.parametrize('name', ['reproduce', 'bench_sim'])
def test_the_main_job_and_bench_sim_name_their_new_options(name):
    out = subprocess.run([str(executable(name)), '--help'], capture_output=True, text=True,
                         timeout=120).stdout
    wanted = {'reproduce': ('--extended', '--stages', '--workers'),
              'bench_sim': ('@magnetic',)}[name]
    assert all(option in out for option in wanted), out
