cd /work/wt/gate; export CANOPY_CACHE_DIR=/work/cache PYTHONPATH=/work/wt/gate
X="--set tracking.vertical_estimate=true --set mapping.attitude_prior=true --set tracking.vertical_max_sigma_deg=0.3 --set tracking.vertical_gate_ratio=0.6"
for s in 0 1 2; do
python benchmarks/diagnose_pitch.py --no-counterfactuals --path /tmp/attitude-cache/day-loop-300-g0.15-b0.06-high-seed$s-rendered \
    --clean /work/cache/synthetic/day-loop-seed0-full --max-frames 300 $X > /tmp/gate/yaw-s$s.log 2>&1
done
