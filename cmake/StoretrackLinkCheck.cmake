# "No production library links the simulator" (docs/architecture.md): after every folder is
# added, storetrack_write_link_closures() writes each library's transitive link closure to
# <build>/storetrack_library_links.txt, one line per library: name|source dir|simulated-mode
# flag|closure (;-list). The test test_no_production_library_links_simulator
# (tests/cmake/check_no_simulator_link.cmake) reads it and fails on any library under host/,
# firmware/ or estimation/ whose closure holds common/sim's libraries, unless the library is the
# simulated side of a split (target property STORETRACK_SIMULATED_MODE, e.g. storetrack_unit_sim).
# tests/cmake/check_layering.cmake reads the same list: no host/ library links a firmware/ one.
# Uses storetrack_collect_targets (StoretrackPch.cmake).

# The library targets `target` links, directly or through others (aliases resolved, generator
# expressions other than $<LINK_ONLY:...> dropped: none of the project's libraries links a
# target only under a condition).
function(storetrack_link_closure target out)
  set(pending ${target})
  set(closure)
  while(pending)
    list(POP_FRONT pending current)
    get_target_property(type ${current} TYPE)
    set(direct)
    if(NOT type STREQUAL "INTERFACE_LIBRARY")
      get_target_property(links ${current} LINK_LIBRARIES)
      if(links)
        list(APPEND direct ${links})
      endif()
    endif()
    get_target_property(interface ${current} INTERFACE_LINK_LIBRARIES)
    if(interface)
      list(APPEND direct ${interface})
    endif()
    foreach(item IN LISTS direct)
      string(REGEX REPLACE "^\\$<LINK_ONLY:(.*)>$" "\\1" item "${item}")
      if(item MATCHES "^\\$<" OR NOT TARGET ${item})
        continue()
      endif()
      get_target_property(aliased ${item} ALIASED_TARGET)
      if(aliased)
        set(item ${aliased})
      endif()
      if(NOT item IN_LIST closure)
        list(APPEND closure ${item})
        list(APPEND pending ${item})
      endif()
    endforeach()
  endwhile()
  set(${out} ${closure} PARENT_SCOPE)
endfunction()

function(storetrack_write_link_closures)
  storetrack_collect_targets(targets ${PROJECT_SOURCE_DIR})
  set(lines)
  foreach(target IN LISTS targets)
    get_target_property(type ${target} TYPE)
    if(NOT type MATCHES "_LIBRARY$" OR type STREQUAL "UNKNOWN_LIBRARY")
      continue()
    endif()
    get_target_property(dir ${target} SOURCE_DIR)
    file(RELATIVE_PATH dir ${PROJECT_SOURCE_DIR} ${dir})
    if(dir STREQUAL "")
      set(dir .)
    endif()
    get_target_property(simulated ${target} STORETRACK_SIMULATED_MODE)
    if(NOT simulated)
      set(simulated OFF)
    endif()
    storetrack_link_closure(${target} closure)
    string(REPLACE ";" "," closure "${closure}")
    string(APPEND lines "${target}|${dir}|${simulated}|${closure}\n")
  endforeach()
  file(WRITE ${PROJECT_BINARY_DIR}/storetrack_library_links.txt "${lines}")
endfunction()
