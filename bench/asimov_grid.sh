#!/usr/bin/env bash
# The 2-parameter study's 3x3 grid on the Asimov data set: the Grad-delta-f
# stand-in's expected values at the truth (eta/s = 0.1, e_sw = 0.2 GeV/fm^3)
# with the study mock's errors and bin covariance, no noise
# (pipeline/heavy_ion_2param_asimov.toml). Needs the study's mock folder
# (`mdpipe run pipeline/heavy_ion_2param.toml`). Prints the README's table.
#
#   bash bench/asimov_grid.sh [MODEL] [PARTICLES]
#
# MODEL is the f_eq model the data are fitted with:
#   smooth (default)  an emulator trained on the stand-in's expected values
#                     (`simulate heavy-ion --design D --out T.parquet`) at 200
#                     maximin points: no run noise, held-out error below 7% of
#                     the data error in every bin, so the stand-in itself;
#   EMULATOR_DIR      an emulator folder, e.g. the study's own
#                     outputs/heavy_ion_2param/refine/round_2/emulator, which
#                     separates what its error adds from what the mock's noise adds.
# With no noise and no emulator error, an MD interval that excludes the truth
# does so because delta's prior lets a shifted theta absorb part of the
# concealed physics. PARTICLES per replicate (4 replicates) defaults to 1000.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
mdpipe="${MDPIPE:-$root/target/release/mdpipe}"
mock="$root/outputs/heavy_ion_2param/mock"
[ -f "$mock/measurements.parquet" ] && [ -f "$mock/covariance.csv" ] || {
  echo "no $mock/measurements.parquet and covariance.csv: run mdpipe run pipeline/heavy_ion_2param.toml first" >&2; exit 1; }
model="${1:-smooth}"
particles="${2:-1000}"
data="$root/outputs/heavy_ion_2param_asimov"
mkdir -p "$data"
"$mdpipe" simulate heavy-ion --point eta_s=0.1,e_sw=0.2 --delta-f grad \
  --errors-from "$mock/measurements.parquet" --out "$data/measurements.csv"

emulator="$data/smooth_emulator"
if [[ "$model" == smooth ]]; then
  if [ ! -f "$emulator/emulator.json" ]; then
    "$mdpipe" design "$root/design/heavy_ion_2param.toml" --points 200 --seed 7 --out "$data/smooth_design"
    "$mdpipe" simulate heavy-ion --design "$data/smooth_design/design.parquet" --delta-f none --out "$data/smooth_training.parquet"
    "$mdpipe" train-emulator "$root/pipeline/heavy_ion_2param.toml" --training "$data/smooth_training.parquet" --out "$emulator"
    "$mdpipe" design "$root/design/heavy_ion_2param.toml" --points 40 --seed 11 --out "$data/smooth_validation_design"
    "$mdpipe" simulate heavy-ion --design "$data/smooth_validation_design/design.parquet" --delta-f none --out "$data/smooth_validation.parquet"
    "$mdpipe" validate-emulator "$emulator" --validation "$data/smooth_validation.parquet"
  fi
else
  emulator="$(realpath "$model")"
fi
out="$data/$(basename "$model")_$particles"
mkdir -p "$out"

# The config, with its relative paths made absolute (the copy lives under
# outputs/), the particles set, and the emulator named.
config="$out/config.toml"
sed -e "s|\"\.\./|\"$root/|g" -e "s|^particles = .*|particles = $particles|" \
  "$root/pipeline/heavy_ion_2param_asimov.toml" > "$config"
sed -i "s|^artifact = .*|artifact = \"$emulator\"|" "$config"

sets=("ch_spectrum" "ch_spectrum,ch_v2,ch_v3" "ch_spectrum,ch_v2,ch_v3,pi_spectrum,pi_v2,p_spectrum,p_v2")
for s in 0 1 2; do
  for k in none I II; do
    [ -f "$out/set${s}_$k/summary.json" ] && continue   # a rerun finishes what is missing
    "$mdpipe" calibrate "$config" --observables "${sets[$s]}" \
      --kernel "$k" --seed 1 --out "$out/set${s}_$k" > "$out/set${s}_$k.log" 2>&1
  done
done

python3 "$root/bench/grid_table.py" "$out"
