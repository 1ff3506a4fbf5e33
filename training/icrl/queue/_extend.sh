# Sourced after _env.sh: the 6 M-step continuation of HalfCheetah's and Ant's PPO-Lagrangian rows, kept in its own root
# ($EXT, committed as training/icrl_6m) so that the 3 M-step report stays whole while it trains. Each run starts
# as a copy of its finished 3 M-step run (checkpoint, logs, config) and continues to 6 M steps.
EXT=${ICRL_EXT:-/work/icrl_6m}
RX="$PY -m pbicrl.cli.icrl_benchmark --out $EXT --run"
extend_copy() {  # task method seed: copy the finished run into $EXT unless there already
    local src=$OUT/$1/$2/seed$3 dst=$EXT/$1/$2/seed$3
    [ -d "$dst" ] && return 0
    [ -f "$src/done.json" ] || { echo "extend: $src is not finished" >&2; return 1; }
    mkdir -p "$EXT/$1/$2" && cp -r "$src" "$dst.tmp" && rm -f "$dst.tmp/lock" && mv "$dst.tmp" "$dst"
}
