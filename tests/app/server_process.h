// ServerProcess: the real `octoscope serve` binary started by a test (fork + exec), its URL read
// from the first line it prints, stopped with SIGTERM. Tests drive it over loopback with real
// HTTP and WebSocket clients (tests/net/net_test_client.h).
#ifndef OCTOSCOPE_TESTS_APP_SERVER_PROCESS_H_
#define OCTOSCOPE_TESTS_APP_SERVER_PROCESS_H_

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace octoscope::testing {

class ServerProcess {
 public:
  ServerProcess() = default;
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;
  ~ServerProcess() { Kill(); }

  // Starts `binary serve args...` with stderr to `log_path`; waits (at most `timeout`) for the URL
  // line. False (and error()) when the process exits first or prints no URL in time.
  bool Start(const std::string& binary, const std::vector<std::string>& args,
             const std::string& log_path, std::chrono::seconds timeout = std::chrono::seconds(60)) {
    int out[2];
    if (pipe(out) != 0) return Fail("pipe");
    pid_ = fork();
    if (pid_ < 0) return Fail("fork");
    if (pid_ == 0) {
      dup2(out[1], 1);
      const int err = open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      if (err >= 0) dup2(err, 2);
      close(out[0]);
      std::vector<char*> argv;
      argv.push_back(const_cast<char*>(binary.c_str()));
      static char serve[] = "serve";
      argv.push_back(serve);
      for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
      argv.push_back(nullptr);
      execv(binary.c_str(), argv.data());
      _exit(127);
    }
    close(out[1]);
    stdout_fd_ = out[0];
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    std::string line;
    while (std::chrono::steady_clock::now() < deadline) {
      pollfd p{stdout_fd_, POLLIN, 0};
      if (poll(&p, 1, 100) <= 0) continue;
      char c;
      const ssize_t n = read(stdout_fd_, &c, 1);
      if (n <= 0) return Fail("exited before printing the URL (see " + log_path + ")");
      if (c == '\n') {
        url_ = line;
        return ParseUrl(log_path);
      }
      line += c;
    }
    return Fail("no URL within the timeout (see " + log_path + ")");
  }

  // SIGTERM, then waits; the exit status (or -1 when it had to be killed, -2 when not running).
  int Stop(std::chrono::seconds timeout = std::chrono::seconds(30)) {
    if (pid_ <= 0) return -2;
    kill(pid_, SIGTERM);
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      int status = 0;
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        CloseStdout();
        return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    Kill();
    return -1;
  }

  void Kill() {
    if (pid_ > 0) {
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
      pid_ = -1;
    }
    CloseStdout();
  }

  bool running() const {
    if (pid_ <= 0) return false;
    return waitpid(pid_, nullptr, WNOHANG) == 0;
  }

  // Resident set size in KiB (VmRSS), 0 when unknown.
  uint64_t RssKiB() const { return StatusKiB("VmRSS:"); }
  // The peak resident set size in KiB (VmHWM) since the start or the last ResetPeakRss.
  uint64_t PeakRssKiB() const { return StatusKiB("VmHWM:"); }
  // Sets the peak (VmHWM) to the present RSS (/proc/PID/clear_refs); false when refused.
  bool ResetPeakRss() const {
    std::ofstream out("/proc/" + std::to_string(pid_) + "/clear_refs");
    out << "5";
    out.flush();
    return out.good();
  }

  const std::string& url() const { return url_; }
  uint16_t port() const { return port_; }
  const std::string& token() const { return token_; }
  const std::string& dataset() const { return dataset_; }
  const std::string& error() const { return error_; }
  pid_t pid() const { return pid_; }

 private:
  uint64_t StatusKiB(const std::string& field) const {
    std::ifstream in("/proc/" + std::to_string(pid_) + "/status");
    std::string key;
    while (in >> key) {
      if (key == field) {
        uint64_t kib = 0;
        in >> kib;
        return kib;
      }
      std::string rest;
      std::getline(in, rest);
    }
    return 0;
  }
  bool Fail(std::string what) {
    error_ = std::move(what);
    return false;
  }
  // BASE/?token=T[&dataset=ID]; the port from the log's "listening on ADDR port N" line (the
  // printed URL is the public URL when one is given).
  bool ParseUrl(const std::string& log_path) {
    std::ifstream log(log_path);
    const std::string marker = " port ";
    for (std::string l; std::getline(log, l);) {
      const size_t at = l.find("listening on ");
      const size_t p = at == std::string::npos ? at : l.find(marker, at);
      if (p != std::string::npos) {
        port_ = static_cast<uint16_t>(std::strtoul(l.c_str() + p + marker.size(), nullptr, 10));
        break;
      }
    }
    if (port_ == 0) return Fail("no \"listening on\" line in " + log_path);
    auto param = [&](const std::string& name) {
      const size_t at = url_.find(name + "=");
      if (at == std::string::npos) return std::string();
      const size_t end = url_.find('&', at);
      return url_.substr(at + name.size() + 1,
                         end == std::string::npos ? std::string::npos : end - at - name.size() - 1);
    };
    token_ = param("token");
    dataset_ = param("dataset");
    return !token_.empty() || Fail("URL without token: " + url_);
  }
  void CloseStdout() {
    if (stdout_fd_ >= 0) close(stdout_fd_);
    stdout_fd_ = -1;
  }

  pid_t pid_ = -1;
  int stdout_fd_ = -1;
  std::string url_, token_, dataset_, error_;
  uint16_t port_ = 0;
};

}  // namespace octoscope::testing

#endif  // OCTOSCOPE_TESTS_APP_SERVER_PROCESS_H_
