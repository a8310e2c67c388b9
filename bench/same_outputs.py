"""Compares two mdpipe output folders made from the same seed (say, by the
binaries before and after a refactor): JSON files without timings and
provenance, Parquet tables column by column (NaN equal to NaN; metadata,
which holds provenance, left out), markdown and HTML up to the folders' paths.

    python3 bench/same_outputs.py OLD NEW     # needs pyarrow (pip install pyarrow)
"""
import json, math, os, sys
import pyarrow.parquet as pq
old, new = sys.argv[1], sys.argv[2]
def clean(v):
    if isinstance(v, dict):
        return {k: clean(x) for k, x in v.items() if k != 'provenance' and 'second' not in k}
    if isinstance(v, list):
        return [clean(x) for x in v]
    if isinstance(v, str):
        return v.replace(old, 'OUT').replace(new, 'OUT')
    return v
def same(x, y):
    return x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))
counts = {'json': [0, 0], 'parquet': [0, 0], 'text': [0, 0]}
for root, _, files in os.walk(old):
    for f in files:
        p = os.path.join(root, f); q = new + p[len(old):]
        if '/stages/' in p or '.attempts' in p or f == 'execution.json':
            continue
        if f.endswith('.json'):
            kind, ok = 'json', clean(json.load(open(p))) == clean(json.load(open(q)))
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
