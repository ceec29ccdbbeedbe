// The compiled parts of Boost.Asio and Boost.Beast, built once for the whole program (both are
// used in separate-compilation mode, see CMakeLists.txt: every other file only declares them).
#include <boost/asio/impl/src.hpp>
#include <boost/beast/src.hpp>
