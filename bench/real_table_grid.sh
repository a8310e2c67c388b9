#!/usr/bin/env bash
# The stand-in's emulator calibrated against the real iEBE-MUSIC table (Grad
# delta-f, eta/s = 0.1, e_sw = 0.2 GeV/fm^3) over the 3x3 grid of observable
# sets and kernels, one `mdpipe calibrate` per case; prints the README's table.
#
#   bash bench/real_table_grid.sh outputs/heavy_ion_2param/refine/round_6/emulator [PARTICLES] [FINAL_STEPS]
#
# PARTICLES per replicate (4 replicates; default 1000) and
# smc.final_steps_per_dim (default 15) apply to every case; the all-seven MD
# cases use 3x the particles and 45 final steps, which they need to converge.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
emulator="$(realpath "${1:?give the emulator folder, e.g. outputs/heavy_ion_2param/refine/round_6/emulator}")"
particles="${2:-1000}"
final_steps="${3:-15}"
mdpipe="${MDPIPE:-$root/target/release/mdpipe}"
out="$root/outputs/real_table_grid"
mkdir -p "$out"

# One config per particle setting: the study's, with the emulator swapped in
# and its relative paths made absolute (the copy lives under outputs/).
config() { # particles final_steps -> path
  local path="$out/config_$1_$2.toml"
  sed -e "s|\"\.\./|\"$root/|g" \
      -e "s|^artifact = .*|artifact = \"$emulator\"|" \
      -e "s|^particles = .*|particles = $1\nfinal_steps_per_dim = $2|" \
      "$root/pipeline/heavy_ion_2param.toml" > "$path"
  echo "$path"
}

sets=("ch_spectrum" "ch_spectrum,ch_v2,ch_v3" "ch_spectrum,ch_v2,ch_v3,pi_spectrum,pi_v2,p_spectrum,p_v2")
for s in 0 1 2; do
  for k in none I II; do
    if [[ $s == 2 && $k != none ]]; then cfg=$(config $((3 * particles)) 45); else cfg=$(config "$particles" "$final_steps"); fi
    "$mdpipe" calibrate "$cfg" --data "$root/pipeline/reference/iebe_music_grad_shear0p1_esw0p2.dat" \
      --observables "${sets[$s]}" --kernel "$k" --seed 1 --out "$out/set${s}_$k" > "$out/set${s}_$k.log" 2>&1
  done
done

python3 "$root/bench/grid_table.py" "$out"
