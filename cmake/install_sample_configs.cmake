# Run by cmake --install and cpack (see cmake/packaging.cmake): installs each sample config in
# canbridge_sample_configs into canbridge_config_dir, but never over an edited one: that stays,
# and the new sample goes beside it as <name>.sample.
# file(INSTALL) puts $ENV{DESTDIR} in front of its destination itself; the checks need it here.
set(dir "${canbridge_config_dir}")
foreach(sample IN LISTS canbridge_sample_configs)
  get_filename_component(name "${sample}" NAME)
  set(installed "$ENV{DESTDIR}${dir}/${name}")
  if(EXISTS "${installed}")
    file(READ "${installed}" current)
    file(READ "${sample}" shipped)
    if(NOT current STREQUAL shipped)
      file(INSTALL DESTINATION "${dir}" TYPE FILE RENAME "${name}.sample" FILES "${sample}"
                 PERMISSIONS OWNER_READ OWNER_WRITE GROUP_READ WORLD_READ)
      message(STATUS "Kept the edited ${installed}; the new sample is ${installed}.sample")
      continue()
    endif()
  endif()
  file(INSTALL DESTINATION "${dir}" TYPE FILE FILES "${sample}"
       PERMISSIONS OWNER_READ OWNER_WRITE GROUP_READ WORLD_READ)
endforeach()
