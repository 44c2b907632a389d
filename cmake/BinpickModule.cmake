# bp_add_module(NAME DIR PUBLIC_DEPS ... PRIVATE_DEPS ...)
# One static library per top-level module; sources are the module's *.cc and
# internal/*.cc files. Public headers live at the module root and are included
# as "module/header.h" from the repository root.
function(bp_add_module name)
  cmake_parse_arguments(ARG "" "" "PUBLIC_DEPS;PRIVATE_DEPS;EXTRA_SOURCES" ${ARGN})
  file(GLOB _srcs CONFIGURE_DEPENDS ${CMAKE_CURRENT_SOURCE_DIR}/*.cc
       ${CMAKE_CURRENT_SOURCE_DIR}/internal/*.cc)
  if(NOT _srcs AND NOT ARG_EXTRA_SOURCES)
    set(_srcs ${PROJECT_SOURCE_DIR}/cmake/empty_module.cc)  # module not written yet
  endif()
  add_library(${name} STATIC ${_srcs} ${ARG_EXTRA_SOURCES})
  target_include_directories(${name} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(${name} PUBLIC ${ARG_PUBLIC_DEPS} PRIVATE ${ARG_PRIVATE_DEPS} bp_warnings)
  # A light module (BINPICK_LIGHT_MODULES: code that waits on sockets, timers
  # and files in the tests) at BINPICK_LIGHT_MODULE_OPT, after the build's
  # level on the command line so it wins; only the module's own files, the
  # modules it calls keep theirs.
  if(BINPICK_LIGHT_MODULE_OPT AND name IN_LIST BINPICK_LIGHT_MODULES)
    target_compile_options(${name} PRIVATE $<$<CONFIG:RelWithDebInfo,Release>:${BINPICK_LIGHT_MODULE_OPT}>)
  endif()
endfunction()

# bp_add_test(NAME DIR DEPS ...): one GoogleTest executable from DIR/*_test.cc.
function(bp_add_test name dir)
  cmake_parse_arguments(ARG "" "" "DEPS" ${ARGN})
  file(GLOB _srcs CONFIGURE_DEPENDS ${dir}/*_test.cc)
  if(NOT _srcs)
    return()
  endif()
  add_executable(${name} ${_srcs} ${PROJECT_SOURCE_DIR}/tests/testing/tsan_serial_tbb.cc)
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} GTest::gtest GTest::gtest_main GTest::gmock TBB::tbb bp_warnings)
  target_compile_definitions(${name} PRIVATE
    BINPICK_SOURCE_DIR="${PROJECT_SOURCE_DIR}" BINPICK_BINARY_DIR="${CMAKE_BINARY_DIR}")
  # Test code is compiled at BINPICK_TEST_OPT (the code under test, in the
  # libraries, keeps the build's level). -O1 by default: measured with GCC, a
  # test file compiles in 60% of the time it takes at -O2 -g
  # (daoai_server_test.cc 14.8 -> 8.4 s), about as fast as at -O0, and runs
  # its loops much faster than at -O0. The sanitizer presets set -O0, where
  # clang's instrumentation at -O1 is most of a test file's compile time;
  # tests/CMakeLists.txt keeps the tests whose Eigen work is in the test code
  # at -O1.
  target_compile_options(${name} PRIVATE $<$<CONFIG:RelWithDebInfo,Release>:${BINPICK_TEST_OPT}>)
  gtest_discover_tests(${name} DISCOVERY_MODE PRE_TEST
    PROPERTIES ENVIRONMENT "BINPICK_ASSETS=${PROJECT_SOURCE_DIR}/assets")
endfunction()

# bp_depend_on_executables(TARGET DIR): TARGET (a custom target) depends on
# every executable target defined in source directory DIR (already added).
function(bp_depend_on_executables target dir)
  get_property(_targets DIRECTORY ${dir} PROPERTY BUILDSYSTEM_TARGETS)
  foreach(t ${_targets})
    get_target_property(_type ${t} TYPE)
    if(_type STREQUAL "EXECUTABLE")
      add_dependencies(${target} ${t})
    endif()
  endforeach()
endfunction()
