"""Compares two mdpipe output folders made from the same seed (say, by the
binaries before and after a refactor): JSON files without timings and
provenance, Parquet tables column by column (NaN equal to NaN; metadata,
which holds provenance, left out), markdown and HTML up to the folders' paths.

    python3 bench/same_outputs.py OLD NEW             # needs pyarrow (pip install pyarrow)
    python3 bench/same_outputs.py OLD NEW --rtol 1e-8 # numbers equal to 8 digits

With --rtol, numbers in JSON and Parquet count as equal when they differ by
at most that fraction of the larger, and the largest relative difference
found is printed (a change of solver that is exact where the old one was
exact to its tolerance moves results in the last digits, not more).
"""
import json, math, os, sys
import pyarrow.parquet as pq
args = [a for a in sys.argv[1:] if not a.startswith('--')]
old, new = args[0], args[1]
rtol = float(sys.argv[sys.argv.index('--rtol') + 1]) if '--rtol' in sys.argv else 0.0
if rtol:
    args = [a for a in args if a != sys.argv[sys.argv.index('--rtol') + 1]]
    old, new = args[0], args[1]
largest = [0.0]
def clean(v):
    if isinstance(v, dict):
        return {k: clean(x) for k, x in v.items() if k != 'provenance' and 'second' not in k}
    if isinstance(v, list):
        return [clean(x) for x in v]
    if isinstance(v, str):
        return v.replace(old, 'OUT').replace(new, 'OUT')
    return v
def same(x, y):
    if x == y:
        return True
    if not (isinstance(x, (int, float)) and isinstance(y, (int, float))) or isinstance(x, bool):
        return False
    if math.isnan(x) and math.isnan(y):
        return True
    scale = max(abs(x), abs(y))
    if not rtol or math.isinf(scale) or scale == 0:
        return False
    largest[0] = max(largest[0], abs(x - y) / scale)
    return abs(x - y) <= rtol * scale
def same_tree(a, b):
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_tree(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_tree(x, y) for x, y in zip(a, b))
    return same(a, b)
counts = {'json': [0, 0], 'parquet': [0, 0], 'text': [0, 0]}
for root, _, files in os.walk(old):
    for f in files:
        p = os.path.join(root, f); q = new + p[len(old):]
        if '/stages/' in p or '.attempts' in p or f == 'execution.json':
            continue
        if f.endswith('.json'):
            kind, ok = 'json', same_tree(clean(json.load(open(p))), clean(json.load(open(q))))
        elif f.endswith('.parquet'):
            a, b = pq.read_table(p), pq.read_table(q)
            kind = 'parquet'
            ok = len(a) == len(b) and all(all(same(x, y) for x, y in zip(a[c].to_pylist(), b[c].to_pylist())) for c in a.column_names if 'second' not in c)
        elif f.endswith('.md') or f.endswith('.html'):
            kind, ok = 'text', open(p).read().replace(old, 'OUT') == open(q).read().replace(new, 'OUT')
        else:
            continue
        counts[kind][0] += 1
        if not ok:
            counts[kind][1] += 1; print('differs:', p)
for k, (n, bad) in counts.items():
    print(f'{k}: {n} compared, {bad} differ')
if rtol:
    print(f'largest relative difference of numbers: {largest[0]:.2e} (tolerance {rtol:.0e})')
