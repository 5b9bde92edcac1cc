# Compiler warnings, sanitizers and ccache for every Lancet target.

option(LANCET_WERROR "Treat warnings as errors (on in CI and in every preset)" OFF)
set(LANCET_SANITIZE "" CACHE STRING "Sanitizers: '', 'address;undefined' or 'thread'")

find_program(LANCET_CCACHE ccache)
if(LANCET_CCACHE)
  set(CMAKE_C_COMPILER_LAUNCHER ${LANCET_CCACHE})
  set(CMAKE_CXX_COMPILER_LAUNCHER ${LANCET_CCACHE})
endif()

add_library(lancet_warnings INTERFACE)
add_library(lancet::warnings ALIAS lancet_warnings)
target_compile_options(lancet_warnings INTERFACE -Wall -Wextra -Wpedantic -Wshadow
                       -Wnon-virtual-dtor -Wold-style-cast -Wcast-align -Wunused
                       -Woverloaded-virtual -Wimplicit-fallthrough)
# GCC 12 at -O3 reports false -Wrestrict errors inside libstdc++'s std::string concatenation
# (GCC bug 105329); they are not in our code.
if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND CMAKE_CXX_COMPILER_VERSION VERSION_LESS 13)
  target_compile_options(lancet_warnings INTERFACE -Wno-restrict)
endif()
if(LANCET_WERROR)
  target_compile_options(lancet_warnings INTERFACE -Werror)
endif()

if(LANCET_SANITIZE)
  string(REPLACE ";" "," _lancet_san "${LANCET_SANITIZE}")
  add_compile_options(-fsanitize=${_lancet_san} -fno-omit-frame-pointer -fno-sanitize-recover=all)
  add_link_options(-fsanitize=${_lancet_san})
endif()

# True when this build is instrumented by a sanitizer; tests use it to scale their workloads.
if(LANCET_SANITIZE MATCHES "thread")
  set(LANCET_TSAN ON)
else()
  set(LANCET_TSAN OFF)
endif()

# lancet_add_library(<module> SOURCES a.cpp ... [PUBLIC deps...] [PRIVATE deps...])
# One library per module: target lancet_<module>, alias lancet::<module>, headers found from the
# module's process folder (e.g. #include "haptics/penalty_contact.hpp"), Lancet's warnings.
function(lancet_add_library module)
  cmake_parse_arguments(L "" "" "SOURCES;PUBLIC;PRIVATE" ${ARGN})
  add_library(lancet_${module} ${L_SOURCES})
  add_library(lancet::${module} ALIAS lancet_${module})
  target_include_directories(lancet_${module} PUBLIC ${CMAKE_CURRENT_SOURCE_DIR})
  target_link_libraries(lancet_${module} PUBLIC ${L_PUBLIC} PRIVATE ${L_PRIVATE} lancet::warnings)
endfunction()
