"""bench_messages times both ways of each half of a frame and writes JSON matching its table."""
import json

from tacforce_ros.benchmarks.bench_messages import main


def test_bench_messages_writes_both_ways_of_both_halves(tmp_path, capsys):
    out = tmp_path / 'messages.json'
    main(['--frames', '60', '--out', str(out)])
    result = json.loads(out.read_text())
    table = capsys.readouterr().out
    for part in ('intake', 'output'):
        assert set(result[part]) == {'message objects', 'serialized'}
        for way in result[part].values():
            assert 0 < way['median_us'] <= way['p99_us']
            assert f'{way["median_us"]:.1f}' in table
        assert f'{result["ratio_median"][part]:.1f}x' in table
