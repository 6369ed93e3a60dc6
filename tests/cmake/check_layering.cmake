# cmake -DROOT=<source tree> [-DLINKS=<build>/storetrack_library_links.txt] -P check_layering.cmake
# The floors of the house (docs/architecture.md): common/ at the bottom, estimation/ on it, and
# firmware/ and host/ side by side above. A wing never reaches into the other, and the floor
# never reaches up. Fails naming each offender when
# - a source or header under host/ includes a firmware/ header, or one under firmware/ a host/
#   header, or one under estimation/ a header of either wing (headers are named by their
#   library's include folder, storetrack/<name>/, found under ROOT/<wing>/*/include/storetrack/);
# - (with LINKS) a library under host/ links one under firmware/ or the other way round, or a
#   library under estimation/ links one under host/ or firmware/, directly or through others.
cmake_minimum_required(VERSION 3.25)

# The include folders (storetrack/<name>) a wing's libraries publish.
function(published_headers wing out)
  file(GLOB dirs LIST_DIRECTORIES true RELATIVE ${ROOT}/${wing} ${ROOT}/${wing}/*/include/storetrack/*)
  set(names)
  foreach(dir IN LISTS dirs)
    get_filename_component(name ${dir} NAME)
    list(APPEND names ${name})
  endforeach()
  set(${out} ${names} PARENT_SCOPE)
endfunction()

# Appends "file includes storetrack/<name>/... (<owner>/)" to `offenders` for every file under
# ROOT/<floor> that includes a header published by `owner`.
function(check_includes floor owner)
  published_headers(${owner} names)
  if(NOT names)
    return()
  endif()
  list(JOIN names "|" alternatives)
  file(GLOB_RECURSE files RELATIVE ${ROOT} ${ROOT}/${floor}/*.hpp ${ROOT}/${floor}/*.cpp
       ${ROOT}/${floor}/*.h ${ROOT}/${floor}/*.cc)
  set(found ${offenders})
  foreach(file IN LISTS files)
    file(STRINGS ${ROOT}/${file} lines REGEX "^[ \t]*#[ \t]*include[ \t]*[\"<]storetrack/(${alternatives})/")
    foreach(line IN LISTS lines)
      string(REGEX MATCH "storetrack/[^\">]+" header "${line}")
      list(APPEND found "${file} includes ${header} (${owner}/)")
    endforeach()
  endforeach()
  set(offenders ${found} PARENT_SCOPE)
endfunction()

if(NOT IS_DIRECTORY "${ROOT}")
  message(FATAL_ERROR "source tree ${ROOT} not found")
endif()
set(offenders)
check_includes(host firmware)
check_includes(firmware host)
check_includes(estimation host)
check_includes(estimation firmware)

set(libraries 0)
if(LINKS)
  if(NOT EXISTS "${LINKS}")
    message(FATAL_ERROR "link list ${LINKS} not found (configure the tree first)")
  endif()
  file(STRINGS "${LINKS}" lines)
  # First pass: each library's floor (the first folder of its source directory).
  foreach(line IN LISTS lines)
    string(REPLACE "|" ";" fields "${line}")
    list(GET fields 0 target)
    list(GET fields 1 dir)
    string(REGEX REPLACE "/.*" "" floor "${dir}")
    set(floor_of_${target} ${floor})
  endforeach()
  set(forbidden_host firmware)
  set(forbidden_firmware host)
  set(forbidden_estimation host firmware)
  foreach(line IN LISTS lines)
    string(REPLACE "|" ";" fields "${line}")
    list(LENGTH fields n)
    list(GET fields 0 target)
    list(GET fields 1 dir)
    set(floor ${floor_of_${target}})
    if(NOT DEFINED forbidden_${floor} OR n LESS 4)
      continue()
    endif()
    math(EXPR libraries "${libraries} + 1")
    list(GET fields 3 closure)
    string(REPLACE "," ";" closure "${closure}")
    foreach(linked IN LISTS closure)
      if(floor_of_${linked} IN_LIST forbidden_${floor})
        list(APPEND offenders "${target} (${dir}) links ${linked} (${floor_of_${linked}}/)")
      endif()
    endforeach()
  endforeach()
endif()

if(offenders)
  list(JOIN offenders "\n  " text)
  message(FATAL_ERROR "a floor reaches past its own: host/ and firmware/ stand side by side on "
                      "estimation/ and common/ (docs/architecture.md):\n  ${text}")
endif()
message(STATUS "no include or link crosses the wings or runs up from estimation/ "
               "(${libraries} libraries' links checked)")
