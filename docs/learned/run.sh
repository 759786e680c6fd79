#!/bin/sh
# The learned reconstructor's held-out evaluation behind the README's table (docs/learned.md):
# 11 min on the shared 2-core machine at load 1-2 (about 80 min at load 12-16). Run from the repository root.
set -e
export OMP_NUM_THREADS=1
P=docs/learned/parts
mkdir -p $P
S="--methods learned tval3 unrolled"
python benchmarks/eval_learned.py --sizes 32 64 128 --srs 0.0625 0.125 $S --out $P/main_a.json
python benchmarks/eval_learned.py --sizes 32 64 --srs 0.25 0.375 $S --out $P/main_b.json
python benchmarks/eval_learned.py --sizes 128 --srs 0.25 0.375 $S --out $P/main_c.json
python benchmarks/eval_learned.py --sizes 256 --srs 0.0625 0.125 --levels 0 0.01 --methods learned tval3 --out $P/main_d.json
python benchmarks/eval_learned.py --sizes 32 64 --srs 0.0625 0.125 --levels 0.01 --methods tval3 auto --out $P/auto_a.json
python benchmarks/eval_learned.py --speed --out $P/speed.json
python benchmarks/eval_learned.py --onnx --out $P/onnx.json
python benchmarks/eval_learned.py --paper --out $P/paper.json
python docs/learned/merge.py $P
