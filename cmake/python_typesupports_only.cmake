# Injected with -DCMAKE_PROJECT_TOP_LEVEL_INCLUDES=... by tools/build_interfaces.sh: generate and
# compile an interface package's C and Python type supports only, not the C++ ones.
#
# rclpy needs the C type supports (rosidl_typesupport_c dispatching to fastrtps_c and
# introspection_c) and the Python extension; the C++ generator and its three type supports
# (typesupport_cpp, fastrtps_cpp, introspection_cpp) only serve rclcpp, and took about 60 % of the
# compile time of simulation_interfaces.  rosidl_default_generators finds every generator in the
# ament index and each one registers itself on the extension point
# rosidl_generate_idl_interfaces when found.  This dependency provider lets every find_package()
# run as usual (fastrtps_c still needs fastrtps_cpp's runtime headers found), then drops the C++
# generators' registrations, so rosidl_generate_interfaces() never runs them.  Nothing is
# edited in the package or the installed generators.
cmake_minimum_required(VERSION 3.24)

macro(vb_find_package_without_cpp_generators method package_name)
  find_package(${package_name} ${ARGN} BYPASS_PROVIDER)
  if(DEFINED AMENT_EXTENSIONS_rosidl_generate_idl_interfaces)
    list(FILTER AMENT_EXTENSIONS_rosidl_generate_idl_interfaces EXCLUDE REGEX
         "^rosidl_(generator_cpp|typesupport_cpp|typesupport_fastrtps_cpp|typesupport_introspection_cpp):")
  endif()
endmacro()

cmake_language(SET_DEPENDENCY_PROVIDER vb_find_package_without_cpp_generators SUPPORTED_METHODS FIND_PACKAGE)
