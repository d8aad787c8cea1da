# Injected with -DCMAKE_PROJECT_INCLUDE=... when building msg_defs against the
# ROS 2 PyPI wheels.  The wheels' exported *__rosidl_generator_py targets carry
# include paths from their build image (/opt/python/cp311-cp311/include/python3.11
# and .../site-packages/numpy/_core/include).  At the end of the top-level
# CMakeLists we rewrite them, on the imported targets only, to this
# interpreter's real include dirs.  Nothing outside the build tree is written.
cmake_minimum_required(VERSION 3.21)

if(NOT DEFINED Python3_EXECUTABLE)
  message(FATAL_ERROR "fix_wheel_include_paths.cmake needs -DPython3_EXECUTABLE")
endif()
execute_process(
  COMMAND "${Python3_EXECUTABLE}" -c "import sysconfig, numpy; print(sysconfig.get_path('include')); print(numpy.get_include())"
  OUTPUT_VARIABLE _vb_out OUTPUT_STRIP_TRAILING_WHITESPACE
  RESULT_VARIABLE _vb_rc)
if(NOT _vb_rc EQUAL 0)
  message(FATAL_ERROR "could not query Python/numpy include dirs from ${Python3_EXECUTABLE}")
endif()
string(REPLACE "\n" ";" _vb_out "${_vb_out}")
list(GET _vb_out 0 VB_PY_INCLUDE)
list(GET _vb_out 1 VB_NUMPY_INCLUDE)

function(vb_fix_wheel_include_paths)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  set(_n 0)
  foreach(_t IN LISTS _targets)
    get_target_property(_inc ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(_inc AND "${_inc}" MATCHES "/opt/python/cp3")
      string(REGEX REPLACE "/opt/python/cp3[0-9]+-cp3[0-9]+/include/python3\\.[0-9]+" "${VB_PY_INCLUDE}" _inc "${_inc}")
      string(REGEX REPLACE "/opt/python/cp3[0-9]+-cp3[0-9]+/lib/python3\\.[0-9]+/site-packages/numpy/_core/include" "${VB_NUMPY_INCLUDE}" _inc "${_inc}")
      set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_inc}")
      math(EXPR _n "${_n} + 1")
    endif()
  endforeach()
  message(STATUS "vesselbot: rewrote build-image include paths on ${_n} imported targets")
endfunction()

cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL vb_fix_wheel_include_paths)
