# Included from tests/CMakeLists.txt. vdb_test writes its own small .vdb files (it includes OpenVDB itself).
add_executable(vdb_test ${CMAKE_CURRENT_LIST_DIR}/vdb_test.cpp)
target_link_libraries(vdb_test PRIVATE haze_vdb OpenVDB::openvdb TBB::tbb GTest::gtest_main)
include(GoogleTest)
gtest_discover_tests(vdb_test DISCOVERY_MODE PRE_TEST PROPERTIES TIMEOUT 300 LABELS vdb)
