"""bench_devices runs every link end to end and writes JSON that matches its table."""
import json

from tacforce_ros.benchmarks.bench_devices import main


def test_bench_devices_writes_json_for_every_device(tmp_path, capsys):
    out = tmp_path / 'bench.json'
    main(['--duration', '0.5', '--out', str(out)])
    results = json.loads(out.read_text())['results']
    assert [r['device'] for r in results] == ['xela', 'netft', 'allegro']
    table = capsys.readouterr().out
    for r in results:
        assert r['delivered'] > 0 and r['latency_us']['n'] > 0
        assert 0 < r['latency_us']['median'] <= r['latency_us']['p99'] <= r['latency_us']['max']
        assert r['malformed'] == 0
        assert f'{r["latency_us"]["median"]:.1f}' in table
