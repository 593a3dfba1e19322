#!/usr/bin/env bash
# Prepares this checkout for a call on a lent GPU machine, and puts it back after.
#
#   scripts/lease-tree.sh pack [--campaign] [--tests] [--no-build] [--baseline REV]
#                                                                     # before the calls
#   scripts/lease-tree.sh unpack                                      # after them
#
# A call takes the working tree with it (tracked files and untracked ones git does not
# ignore), at most 64 MiB, and the checkout's tracked networks, models and results are far
# more. `pack`:
#   - builds `pvrnn` (release) and strips it into lease/ (with --tests also the wgpu
#     backend suite, the wgpu crate's tests and device_times as lease/suite-wgpu,
#     lease/wgpu-it (`lease/wgpu-it agrees_with_cpu::` runs those) and lease/device-times, and the overlap probe, `cargo bench -p
#     pvrnn-wgpu --bench overlap`, compressed as lease/overlap-bench.gz: the call runs
#     `gunzip -c lease/overlap-bench.gz > /tmp/overlap && chmod +x /tmp/overlap` and gives
#     it to gpu-measure.sh as OVERLAP_BENCH=/tmp/overlap); --no-build skips the building;
#   - with --baseline REV, also builds commit REV's `pvrnn` (in a worktree beside this
#     checkout, its own target folder) as lease/pvrnn-before.gz, stripped and compressed
#     (about a third of its size: beside the rest it would not fit the 64 MiB); the call
#     runs `gunzip -c lease/pvrnn-before.gz > /tmp/pvrnn-before && chmod +x
#     /tmp/pvrnn-before` first, then `scripts/gpu-measure.sh` with BASELINE=/tmp/pvrnn-before;
#   - downloads the Vulkan loader's Debian packages into .gl/ if missing (docs/gpu.md:
#     NVIDIA's driver needs glvnd's libraries beside the loader);
#   - has .git/info/exclude ignore lease/ and .gl/ (the call carries them: `carry`
#     ["lease", ".gl"]);
#   - drops the folders a call does not need from the index and ignores them for the
#     calls: models/, assets/, docs/ and training/, but with --campaign the interference
#     plan and results (docs/results/converged/interference/) and a kept training
#     (training/in-flight/), which `scripts/lease-campaign.sh` needs;
#   - prints what would travel and its size.
# The files stay on disk. Until `unpack` the index says they are deleted: commit nothing
# in between (pack refuses a second pack and staged changes; unpack restores the index
# to HEAD and the exclude file as it was).
set -euo pipefail
cd "$(dirname "$0")/.."

exclude=.git/info/exclude
marker="# scripts/lease-tree.sh pack: until unpack"
dropped=(models assets docs training)

unpack() {
    if ! grep -qxF "$marker" "$exclude" 2>/dev/null; then
        echo "not packed: nothing to undo" >&2
        exit 1
    fi
    git reset -q
    # Everything from the marker on is pack's.
    awk -v marker="$marker" '$0 == marker { exit } { print }' "$exclude" >"$exclude.tmp"
    mv "$exclude.tmp" "$exclude"
    echo "unpacked: the index is HEAD's again" >&2
}

# What a call would take, in MiB: tracked files, untracked files git does not ignore, and
# the carried folders.
travelling() {
    local bytes carried
    bytes=$({ git ls-files -z; git ls-files -z --others --exclude-standard; } |
        { xargs -0 -r stat -c %s -- 2>/dev/null || true; } | awk '{ s += $1 } END { print s + 0 }')
    carried=$(du -sb lease .gl 2>/dev/null | awk '{ s += $1 } END { print s + 0 }')
    echo $(((bytes + carried) / 1048576))
}

case "${1:-}" in
unpack)
    unpack
    exit 0
    ;;
pack) shift ;;
*)
    echo "usage: scripts/lease-tree.sh pack [--campaign] [--tests] [--no-build] [--baseline REV] | unpack" >&2
    exit 2
    ;;
esac

campaign=0 tests=0 build=1 baseline=
while [ $# -gt 0 ]; do
    case "$1" in
    --campaign) campaign=1 ;;
    --tests) tests=1 ;;
    --no-build) build=0 ;;
    --baseline)
        baseline=${2:?--baseline needs a commit}
        shift
        ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
    esac
    shift
done
if [ -n "$baseline" ] && ! git rev-parse -q --verify "$baseline^{commit}" >/dev/null; then
    echo "--baseline $baseline: not a commit of this repository" >&2
    exit 1
fi
if grep -qxF "$marker" "$exclude" 2>/dev/null; then
    echo "already packed: run scripts/lease-tree.sh unpack first" >&2
    exit 1
fi
if ! git diff --cached --quiet; then
    echo "staged changes: commit or unstage them first (unpack resets the index to HEAD)" >&2
    exit 1
fi

mkdir -p lease
if [ "$build" = 1 ]; then
    cargo build --release -p pvrnn-cli --bin pvrnn
    target=${CARGO_TARGET_DIR:-target}
    cp "$target/release/pvrnn" lease/pvrnn
    built=(lease/pvrnn)
    if [ "$tests" = 1 ]; then
        for spec in "pvrnn-backend-tests wgpu suite-wgpu" \
            "pvrnn-wgpu it wgpu-it" \
            "pvrnn-wgpu device_times device-times"; do
            read -r package test name <<<"$spec"
            executable=$(cargo test --release -p "$package" --test "$test" --no-run \
                --message-format=json 2>/dev/null | python3 -c '
import json, sys
for line in sys.stdin:
    message = json.loads(line)
    if message.get("executable") and message.get("profile", {}).get("test"):
        print(message["executable"])')
            cp "$executable" "lease/$name"
            built+=("lease/$name")
        done
        probe=$(cargo bench -p pvrnn-wgpu --bench overlap --no-run --message-format=json \
            2>/dev/null | python3 -c '
import json, sys
for line in sys.stdin:
    message = json.loads(line)
    if message.get("executable") and message["target"]["name"] == "overlap":
        print(message["executable"])')
        cp "$probe" lease/overlap-bench
        strip lease/overlap-bench
        gzip -9f lease/overlap-bench
    fi
    strip "${built[@]}"
fi
if [ -n "$baseline" ]; then
    # Beside the checkout, so that the build finds ../shared as this one does.
    tree=$(realpath ..)/lease-baseline-$$
    target=$(realpath "${CARGO_TARGET_DIR:-target}")/baseline
    git worktree add -q --detach "$tree" "$baseline"
    if ! (cd "$tree" && CARGO_TARGET_DIR="$target" cargo build --release -p pvrnn-cli --bin pvrnn); then
        git worktree remove --force "$tree"
        echo "--baseline $baseline: the build failed" >&2
        exit 1
    fi
    git worktree remove --force "$tree"
    cp "$target/release/pvrnn" lease/pvrnn-before
    strip lease/pvrnn-before
    gzip -9f lease/pvrnn-before
fi
if ! compgen -G ".gl/libvulkan1_*.deb" >/dev/null; then
    mkdir -p .gl
    (cd .gl && apt-get download libvulkan1 libglvnd0 libegl1 libgl1 libglx0 libgles2 \
        libopengl0 2>&1 | tail -n 1)
fi

mkdir -p .git/info
touch "$exclude"
for path in /lease/ /.gl/; do
    grep -qxF "$path" "$exclude" || echo "$path" >>"$exclude"
done
{
    echo "$marker"
    for folder in "${dropped[@]}"; do echo "/$folder/"; done
} >>"$exclude"
git rm -r -q --cached --ignore-unmatch -- "${dropped[@]}"
if [ "$campaign" = 1 ]; then
    for kept in docs/results/converged/interference training/in-flight; do
        if [ -e "$kept" ]; then git add -f -- "$kept"; fi
    done
fi
echo "packed: $(travelling) MiB would travel (at most 64); carry [\"lease\", \".gl\"];" \
    "run scripts/lease-tree.sh unpack after the calls, before any commit" >&2
