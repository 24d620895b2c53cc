# Sourced by tools/demo.sh and tools/test.sh: the product tree `build-quickstart/`, the one build of canbridge
# that both quick-start commands use. demo.sh builds the `canbridge` executable in it; test.sh
# adds the system tests and the programs of the rig to the same tree, so that a run of both (as
# .ci/run makes) compiles the product once. Both must configure it with exactly these flags, or
# the second would recompile everything the first built.
# A user's build: warnings stay warnings (CANBRIDGE_WERROR is off), so that a newer compiler's new
# warning cannot stop the quick start. Its compiler launcher, tools/keep-warnings.sh, keeps each
# object's warnings beside it, and tools/test.sh fails on any: CI holds this -O2 build to no
# warnings at all, as the sanitizer tree (-O0) and the armhf tree (-O2) with -Werror.
# -O2, the optimisation every shipped build uses (the .deb, the image, the ARM builds): GCC 12 at
# Release's default -O3 took 7 minutes for the gateway executable alone on a 2-core machine.
# Unity batches: a build from scratch, which this nearly always is, takes ~40 % less compiler time.
# shellcheck shell=bash
product_tree=$root/build-quickstart
product_tree_flags=(-G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS_RELEASE="-O2 -DNDEBUG"
  -DCANBRIDGE_UNITY_BUILD=ON -DCANBRIDGE_WERROR=OFF
  -DCMAKE_CXX_COMPILER_LAUNCHER="$root/tools/keep-warnings.sh")
