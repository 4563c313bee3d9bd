# Shared by cross/build, cross/test and cross/package; sourced, not run.
# Usage: source cross/common.sh v5|v6
#
# v5: Nao V5, Atom Z530 (32-bit, SSSE3): i686-unknown-linux-gnu, -C target-cpu=atom, tests
#     under qemu-i386 -cpu n270. The i686 standard library comes from Debian's i386
#     libstd-rust-web-dev, unpacked into a project-local sysroot.
# v6: Nao V6, Atom E3845 (x86_64, SSE4.2, no AVX): x86_64-unknown-linux-gnu,
#     -C target-cpu=silvermont, tests under qemu-x86_64 with a CPU model without AVX.
# Both are compiled by Debian's rustc-web (/usr/bin/rustc), driven by the project's cargo.

set -euo pipefail

variant="${1:-}"
case "$variant" in
    v5 | v6) ;;
    *)
        echo "usage: $0 v5|v6   (v5: Nao V5, 32-bit Atom; v6: Nao V6, x86_64 Atom)" >&2
        exit 2
        ;;
esac

repository="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cache="${DRIBBLE_CROSS_CACHE:-$HOME/.cache/dribble/cross}"
export CARGO_TARGET_DIR="$cache/target-$variant"
[ -x "$HOME/.cargo/bin/cargo" ] && export PATH="$HOME/.cargo/bin:$PATH"

as_root() {
    if [ "$(id -u)" -eq 0 ]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"; else
        echo "cross: need root (or sudo) to run: $*" >&2
        exit 1
    fi
}

# Debian packages: the compiler, the i686 linker and C library, the emulators.
ensure_packages() {
    local missing=() package
    for package in rustc-web gcc-i686-linux-gnu libc6-dev-i386-cross qemu-user binutils; do
        dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" ||
            missing+=("$package")
    done
    if [ ${#missing[@]} -gt 0 ]; then
        echo "cross: installing ${missing[*]}"
        as_root apt-get update -qq
        as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
    fi
}

rustc_version() {
    dpkg-query -W -f='${Version}' rustc-web
}

# The i686 standard library, matching rustc-web exactly. First choice: Debian's i386 build
# of libstd-rust-web-dev, unpacked into $cache/sysroot-<version> (sets $sysroot). apt
# cannot install it on amd64, so it is downloaded with apt-get download from i386 package
# lists kept in a private directory (the system's apt state is not touched). The i386 lists
# are sometimes served mid-sync; when they stay broken, returns 1 and the caller builds the
# standard library from Debian's rust-web-src instead.
ensure_i686_sysroot() {
    local version state deb lists_ok=0 try
    version="$(rustc_version)"
    sysroot="$cache/sysroot-$version/usr"
    if [ -d "$sysroot/lib/rustlib/i686-unknown-linux-gnu/lib" ]; then
        return 0
    fi
    state="$cache/apt"
    mkdir -p "$state/lists/partial" "$state/cache/archives/partial" "$cache/debs"
    local apt_options=(
        -o "Dir::State::Lists=$state/lists"
        -o "Dir::Cache=$state/cache"
        -o "APT::Architectures::=amd64"
        -o "APT::Architectures::=i386"
    )
    for try in 1 2; do
        if apt-get "${apt_options[@]}" update -qq 2>"$cache/apt-update.log" &&
            ! grep -q '^E:' "$cache/apt-update.log"; then
            lists_ok=1
            break
        fi
        echo "cross: i386 package lists incomplete (try $try of 2)" >&2
        sleep 3
    done
    (cd "$cache/debs" && apt-get "${apt_options[@]}" download "libstd-rust-web-dev:i386=$version" 2>/dev/null) || {
        echo "cross: cannot download libstd-rust-web-dev:i386 $version" >&2
        [ "$lists_ok" = 1 ] || sed 's/^/  apt: /' "$cache/apt-update.log" >&2
        return 1
    }
    deb="$(ls "$cache"/debs/libstd-rust-web-dev_*_i386.deb | head -n 1)"
    mkdir -p "$cache/sysroot-$version"
    dpkg-deb -x "$deb" "$cache/sysroot-$version"
    echo "cross: i686 standard library unpacked into $sysroot"
}

# Fallback: build the i686 standard library from Debian's rust-web-src (the same version as
# the compiler) with cargo's build-std, unlocked on the stable toolchain by RUSTC_BOOTSTRAP.
use_std_from_source() {
    dpkg-query -W -f='${Status}' rust-web-src 2>/dev/null | grep -q "install ok installed" || {
        echo "cross: installing rust-web-src to build the i686 standard library"
        as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends rust-web-src
    }
    export RUSTC_BOOTSTRAP=1
    CARGO_STD_FLAGS=(-Zbuild-std)
    echo "cross: building the i686 standard library from /usr/lib/rustlib/src/rust"
}

# Extra cargo flags (build-std when the i686 library is built from source).
CARGO_STD_FLAGS=()

# Robot binaries (and the tests that run them) link the C library statically, so they start
# on any robot image whatever its glibc (cross/README.md, "glibc on the robot").
STATIC="-C target-feature=+crt-static"

# Sets TARGET and the cargo environment for the variant.
configure_target() {
    export CARGO_BUILD_RUSTC=/usr/bin/rustc CARGO_BUILD_RUSTDOC=/usr/bin/rustdoc
    case "$variant" in
        v5)
            TARGET=i686-unknown-linux-gnu
            export CARGO_TARGET_I686_UNKNOWN_LINUX_GNU_LINKER=i686-linux-gnu-gcc
            # The route that worked last time is kept, so builds are not redone each time the
            # i386 package lists come and go.
            local route_file="$cache/v5-std-route"
            mkdir -p "$cache"
            if [ "$(cat "$route_file" 2>/dev/null)" != source ] && ensure_i686_sysroot; then
                echo debian-i386 >"$route_file"
                export CARGO_TARGET_I686_UNKNOWN_LINUX_GNU_RUSTFLAGS="--sysroot $sysroot -C target-cpu=atom $STATIC"
                # rustdoc reads none of the target's RUSTFLAGS: without the sysroot, the
                # crate's doc-tests (run by `cargo test` with no target selection) find no
                # i686 std. With --target given, cargo passes these to the target's crates only.
                export RUSTDOCFLAGS="--sysroot $sysroot -C target-cpu=atom $STATIC"
            else
                echo source >"$route_file"
                use_std_from_source
                export CARGO_TARGET_I686_UNKNOWN_LINUX_GNU_RUSTFLAGS="-C target-cpu=atom $STATIC"
            fi
            RUNNER="qemu-i386 -cpu n270 -L /usr/i686-linux-gnu"
            STRIP=i686-linux-gnu-strip
            export CARGO_TARGET_I686_UNKNOWN_LINUX_GNU_RUNNER="$RUNNER"
            ;;
        v6)
            TARGET=x86_64-unknown-linux-gnu
            export CARGO_TARGET_X86_64_UNKNOWN_LINUX_GNU_RUSTFLAGS="-C target-cpu=silvermont $STATIC"
            # Silvermont: SSE4.2, POPCNT, MOVBE, AES, RDRAND, and no AVX at all.
            RUNNER="qemu-x86_64 -cpu Westmere,+movbe,+rdrand"
            STRIP=strip
            export CARGO_TARGET_X86_64_UNKNOWN_LINUX_GNU_RUNNER="$RUNNER"
            ;;
    esac
    # The controller's tests start the controller binary; it runs under the same emulator.
    export DRIBBLE_TEST_RUNNER="$RUNNER"
}

# The robot build must not link simulator code: nothing of the simulator in its tree.
check_no_simulator_code() {
    local tree
    tree="$(cd "$repository" && cargo tree -p dribble-controller --target "$TARGET" -e normal,build --prefix none)"
    if grep -E '^(dribble-sim|rapier3d|parry3d|wgpu|naga) ' <<<"$tree"; then
        echo "cross: the controller's dependency tree contains simulator crates (above)" >&2
        exit 1
    fi
    echo "cross: dependency tree checked: $(sort -u <<<"$tree" | wc -l) crates, none from the simulator"
}

# The C library the binary needs: none when statically linked, else the newest glibc symbol
# version it uses.
glibc_requirement() {
    if ! readelf -d "$1" | grep -q '(NEEDED)'; then
        echo "no C library (statically linked)"
    else
        objdump -T "$1" | grep -o 'GLIBC_[0-9.]*' | sort -Vu | tail -n 1
    fi
}

ensure_packages
configure_target
