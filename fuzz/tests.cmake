# The libFuzzer harnesses in the test suite (included by tests/CMakeLists.txt): the product stays
# built by the project's compiler (g++); the harnesses are built by clang with libFuzzer, ASan and
# UBSan in a build of their own (build/fuzz-build, an ExternalProject configured with
# -DOCTOSCOPE_FUZZ=ON, as fuzz/run.sh does), and each becomes a ctest entry that fuzzes it for a
# bounded time from its seeds and regressions (fuzz/ci_run.sh). What a run finds fails the test;
# fixed, it becomes a regression file that the replay tests (tests/io/bad_input_test.cpp,
# tests/io/zarr_fuzz_replay_test.cpp, tests/protocol/ws_fuzz_replay_test.cpp) run every time.
find_program(OCTOSCOPE_CLANGXX clang++)
find_program(OCTOSCOPE_CLANG clang)
# On when clang is found. By default the WebSocket message parser (what every client can reach)
# is fuzzed in every run: its sanitizer build takes ≈ 5 min on 2 cores, the run 30 s. Every
# harness: -DOCTOSCOPE_FUZZ_SECONDS="ws_message_fuzzer=20;dataset_json_fuzzer=6;
# zarr_metadata_fuzzer=6;chunk_codec_fuzzer=6;zarr_store_fuzzer=8;tiff_ome_fuzzer=10" (the
# sanitizer build of every library then takes ≈ 15 min).
if(OCTOSCOPE_CLANGXX AND OCTOSCOPE_CLANG)
  set(fuzz_default ON)
else()
  set(fuzz_default OFF)
endif()
option(OCTOSCOPE_FUZZ_TESTS "Fuzz harnesses for a bounded time in ctest (needs clang + libFuzzer)"
  ${fuzz_default})
# Seconds of fuzzing per harness (ctest entries fuzz.HARNESS, label "fuzz").
set(OCTOSCOPE_FUZZ_SECONDS "ws_message_fuzzer=30"
  CACHE STRING "HARNESS=SECONDS pairs of the fuzz ctest entries")
if(NOT OCTOSCOPE_FUZZ_TESTS)
  return()
endif()

include(ExternalProject)
set(fuzz_build ${CMAKE_BINARY_DIR}/fuzz-build)
set(fuzz_san "-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer")
set(fuzz_targets)
set(fuzz_build_args)
foreach(pair IN LISTS OCTOSCOPE_FUZZ_SECONDS)
  string(REPLACE "=" ";" pair "${pair}")
  list(GET pair 0 harness)
  list(APPEND fuzz_targets ${harness})
  list(APPEND fuzz_build_args --target ${harness})
endforeach()
set(fuzz_byproducts)
foreach(harness IN LISTS fuzz_targets)
  list(APPEND fuzz_byproducts ${fuzz_build}/fuzz/${harness})
endforeach()
ExternalProject_Add(octoscope_fuzzers
  SOURCE_DIR ${CMAKE_SOURCE_DIR}
  BINARY_DIR ${fuzz_build}
  CMAKE_GENERATOR ${CMAKE_GENERATOR}
  CMAKE_ARGS
    -DCMAKE_C_COMPILER=${OCTOSCOPE_CLANG}
    -DCMAKE_CXX_COMPILER=${OCTOSCOPE_CLANGXX}
    -DCMAKE_C_COMPILER_LAUNCHER=${CMAKE_C_COMPILER_LAUNCHER}
    -DCMAKE_CXX_COMPILER_LAUNCHER=${CMAKE_CXX_COMPILER_LAUNCHER}
    -DCMAKE_BUILD_TYPE=RelWithDebInfo
    -DOCTOSCOPE_FUZZ=ON
    -DOCTOSCOPE_BUILD_TESTS=OFF
    "-DCMAKE_CXX_FLAGS=-fsanitize=fuzzer-no-link ${fuzz_san}"
    "-DCMAKE_C_FLAGS=${fuzz_san}"
    "-DCMAKE_EXE_LINKER_FLAGS=${fuzz_san}"
  BUILD_COMMAND ${CMAKE_COMMAND} --build ${fuzz_build} ${fuzz_build_args}
  BUILD_BYPRODUCTS ${fuzz_byproducts}
  INSTALL_COMMAND ""
  # The sources are this checkout: let the sub-build decide what changed.
  BUILD_ALWAYS ON
  # Built by the test fixture below, not by every `cmake --build` (the demo needs no fuzzers).
  EXCLUDE_FROM_ALL ON)
# ctest builds the harnesses first (a fixture every fuzz entry requires).
add_test(NAME fuzz.build
  COMMAND ${CMAKE_COMMAND} --build ${CMAKE_BINARY_DIR} --target octoscope_fuzzers)
set_tests_properties(fuzz.build PROPERTIES LABELS fuzz TIMEOUT 2400 FIXTURES_SETUP fuzzers)

foreach(pair IN LISTS OCTOSCOPE_FUZZ_SECONDS)
  string(REPLACE "=" ";" pair "${pair}")
  list(GET pair 0 harness)
  list(GET pair 1 seconds)
  add_test(NAME fuzz.${harness}
    COMMAND bash ${CMAKE_SOURCE_DIR}/fuzz/ci_run.sh ${fuzz_build}/fuzz/${harness} ${seconds}
      ${CMAKE_BINARY_DIR}/fuzz-runs/${harness})
  # Startup (loading the seeds) and sanitizers on top of the fuzzing time.
  math(EXPR timeout "${seconds} * 3 + 60")
  set_tests_properties(fuzz.${harness} PROPERTIES LABELS fuzz TIMEOUT ${timeout}
    FIXTURES_REQUIRED fuzzers)
endforeach()
