#!/usr/bin/env bash
# The highway-env table of docs/highway-env.md: every command, in order (each resumes where it stopped).
# Usage: scripts/highway_env_table.sh STAGE...   stages: bank dilu speedup merge dense25 dense3 idm-fallback mobil kcline
# Outputs under runs/highway-env/ (not in git). Run it through the heavy lock on a shared machine.
set -euo pipefail
R=runs/highway-env
PLANNERS=(--planner sf --planner he-idm --planner frenet --planner sf-check --planner letspi-fast --planner he-lane-keeper)
LLM=(--memory "$R/bank.sqlite" --no-cache)
for stage in "$@"; do
  case "$stage" in
    bank)  # letspi-fast's memories: collected on letspi's own SUMO traffic (seed 22), never on highway-env
      letspi data generate --out "$R/train_highd" --minutes 10 --seed 22
      letspi data scenarios --highd "$R/train_highd" --out "$R/train.arrow" --max 300 --seed 22
      letspi collect --scenarios "$R/train.arrow" --memory "$R/bank.sqlite" --limit 200 ;;
    dilu)
      letspi benchmark run highway-env-dilu "${PLANNERS[@]}" "${LLM[@]}" --workers 2 --out "$R/dilu" ;;
    speedup)  # the same 20 episodes of sf in one and in two worker processes
      for w in 1 2; do
        /usr/bin/time -f "workers $w: %e s wall" letspi highway-env run --planner sf --workers $w \
          --out "$R/speedup-$w" --n-seeds 20 --set lanes_count=4 --set vehicles_density=2 --set vehicles_count=50 \
          --set ego_spacing=4 --set duration=30 --set simulation_frequency=15
      done ;;
    merge)
      letspi benchmark run highway-env-merge "${PLANNERS[@]}" "${LLM[@]}" --workers 2 --out "$R/merge" ;;
    dense25)
      letspi benchmark run highway-env-dilu-5lane-2.5 "${PLANNERS[@]}" "${LLM[@]}" --workers 2 --out "$R/dense25" ;;
    dense3)
      letspi benchmark run highway-env-dilu-5lane-3 "${PLANNERS[@]}" "${LLM[@]}" --workers 2 --out "$R/dense3" ;;
    idm-fallback)  # sf-check and letspi-fast with the shield's IDM fallback, beside the rows above
      for suite in highway-env-dilu-5lane-3:dense3 highway-env-dilu:dilu highway-env-dilu-5lane-2.5:dense25 \
          highway-env-merge:merge; do
        letspi benchmark run "${suite%%:*}" --planner check-idm=sf-check --planner fast-idm=letspi-fast --idm-fallback \
          "${LLM[@]}" --workers 2 --out "$R/${suite##*:}"
      done ;;
    mobil)  # IDM + MOBIL goals (--goals mobil), alone and with the shield's IDM fallback
      for suite in highway-env-dilu-5lane-3:dense3 highway-env-dilu:dilu highway-env-dilu-5lane-2.5:dense25 \
          highway-env-merge:merge; do
        letspi benchmark run "${suite%%:*}" --planner sf-mobil=sf --planner fast-mobil=letspi-fast --goals mobil \
          "${LLM[@]}" --workers 2 --out "$R/${suite##*:}"
        letspi benchmark run "${suite%%:*}" --planner fast-mobil-idm=letspi-fast --goals mobil --idm-fallback \
          "${LLM[@]}" --workers 2 --out "$R/${suite##*:}"
      done
      letspi benchmark run highway-env-dilu-5lane-3 --planner check-mobil-idm=sf-check --goals mobil --idm-fallback \
        "${LLM[@]}" --workers 2 --out "$R/dense3" ;;
    verify-off)  # letspi-fast since issue 36 (the model's answer stands), beside the rows above (made with --verify)
      for suite in highway-env-dilu-5lane-3:dense3 highway-env-dilu-5lane-2.5:dense25 highway-env-merge:merge \
          highway-env-dilu:dilu; do
        letspi benchmark run "${suite%%:*}" --planner fast-nv=letspi-fast "${LLM[@]}" --workers 2 --out "$R/${suite##*:}"
      done ;;
    kcline)  # a probe: sf with mobil goals and the shipped fit's lane-line well k_cline lowered by hand
      for kc in 0.1 0.25; do
        python -c "import json, sys; from importlib.resources import files
d = json.loads(files('letspi').joinpath('data/sf_params.json').read_text())
d['params']['k_cline'] = float(sys.argv[1]); d['provenance'] = {'note': 'shipped fit, k_cline set by hand'}
json.dump(d, open(sys.argv[2], 'w'), indent=1)" "$kc" "$R/sf_params_kc$kc.json"
        letspi benchmark run highway-env-dilu --planner "sf-mobil-kc$kc=sf" --goals mobil \
          --sf-params "$R/sf_params_kc$kc.json" --workers 2 --out "$R/dilu"
      done
      letspi benchmark run highway-env-dilu-5lane-3 --planner sf-mobil-kc0.1=sf --goals mobil \
        --sf-params "$R/sf_params_kc0.1.json" --workers 2 --out "$R/dense3" ;;
    *) echo "unknown stage $stage" >&2; exit 2 ;;
  esac
done
