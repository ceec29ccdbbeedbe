// Helpers of the deploy tests: running a command, a self-signed certificate made with openssl,
// and Debian's nginx started as the test's own user on loopback ports with a shipped site file
// (deploy/nginx/*.conf) rendered for the test: listen ports, certificate and upstream port
// replaced, IPv6 listeners dropped, everything nginx writes (pid, logs, temp files) in the test's
// folder. Every replacement must match the shipped file, so a changed site breaks the test
// instead of silently testing something else.
//
// Thread safety: one object per test.
#ifndef OCTOSCOPE_TESTS_DEPLOY_NGINX_PROXY_H_
#define OCTOSCOPE_TESTS_DEPLOY_NGINX_PROXY_H_

#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "net/net_test_client.h"

namespace octoscope::deploy::testing {

namespace fs = std::filesystem;

struct CommandResult {
  int status = -1;     // Exit status; -1 when it could not run or was killed.
  std::string output;  // stdout and stderr together.
};

// Runs `command` with /bin/sh (stderr joined to stdout).
inline CommandResult RunCommand(const std::string& command) {
  CommandResult result;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return result;
  std::array<char, 4096> chunk;
  size_t n;
  while ((n = fread(chunk.data(), 1, chunk.size(), pipe)) > 0)
    result.output.append(chunk.data(), n);
  const int status = pclose(pipe);
  result.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

// The full path of `program` on the PATH (or in /usr/sbin, where Debian puts nginx), "" if none.
inline std::string FindProgram(const std::string& program) {
  std::string path = std::getenv("PATH") ? std::getenv("PATH") : "";
  path += ":/usr/sbin:/sbin";
  std::istringstream dirs(path);
  for (std::string dir; std::getline(dirs, dir, ':');) {
    const fs::path candidate = fs::path(dir) / program;
    if (!dir.empty() && access(candidate.c_str(), X_OK) == 0) return candidate.string();
  }
  return "";
}

inline std::string ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

inline void WriteFile(const fs::path& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

// A free TCP port on 127.0.0.1 (bound and released: another process could take it meanwhile,
// which then fails the start with a clear message).
inline uint16_t FreePort() {
  boost::asio::io_context ioc;
  boost::asio::ip::tcp::acceptor acceptor(ioc, {boost::asio::ip::make_address("127.0.0.1"), 0});
  return acceptor.local_endpoint().port();
}

// A self-signed certificate for "localhost" and 127.0.0.1 (P-256, one day); "" or the error.
inline std::string MakeCertificate(const fs::path& dir) {
  const CommandResult r = RunCommand(
      "openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 1 "
      "-subj /CN=localhost -addext subjectAltName=DNS:localhost,IP:127.0.0.1 -keyout '" +
      (dir / "key.pem").string() + "' -out '" + (dir / "cert.pem").string() + "'");
  return r.status == 0 ? "" : "openssl: " + r.output;
}

struct NginxPorts {
  uint16_t https = 0;
  uint16_t http = 0;
  uint16_t upstream = 0;
};

class NginxProxy {
 public:
  NginxProxy() = default;
  NginxProxy(const NginxProxy&) = delete;
  NginxProxy& operator=(const NginxProxy&) = delete;
  ~NginxProxy() { Stop(); }

  // Writes dir/site.conf (the shipped `site` rendered for the test) and dir/nginx.conf (a main
  // configuration that includes it, as Debian's includes sites-enabled/*); "" or what did not
  // match. dir must hold cert.pem and key.pem.
  std::string Render(const fs::path& site, const fs::path& dir, const NginxPorts& ports) {
    dir_ = dir;
    std::string text = ReadFile(site);
    if (text.empty()) return site.string() + ": cannot read";
    struct Rule {
      const char* pattern;
      std::string replacement;
    };
    const std::vector<Rule> rules = {
        {R"(listen 443 ssl http2;)",
         "listen 127.0.0.1:" + std::to_string(ports.https) + " ssl http2;"},
        {R"(listen 80;)", "listen 127.0.0.1:" + std::to_string(ports.http) + ";"},
        {R"(listen \[::\]:(443 ssl http2|80);)", "# (IPv6 listener dropped by the test)"},
        {R"(ssl_certificate +/\S+;)", "ssl_certificate " + (dir / "cert.pem").string() + ";"},
        {R"(ssl_certificate_key +/\S+;)",
         "ssl_certificate_key " + (dir / "key.pem").string() + ";"},
        {R"(server 127\.0\.0\.1:8080;)",
         "server 127.0.0.1:" + std::to_string(ports.upstream) + ";"},
    };
    for (const Rule& rule : rules) {
      const std::regex re(rule.pattern);
      if (!std::regex_search(text, re)) return site.string() + ": no '" + rule.pattern + "'";
      text = std::regex_replace(text, re, rule.replacement);
    }
    WriteFile(dir / "site.conf", text);
    const std::string d = dir.string();
    WriteFile(dir / "nginx.conf",
              "worker_processes 1;\n"
              "pid " +
                  d +
                  "/nginx.pid;\n"
                  "error_log " +
                  d +
                  "/error.log info;\n"
                  "events { worker_connections 256; }\n"
                  "http {\n"
                  "  include /etc/nginx/mime.types;\n"
                  "  default_type application/octet-stream;\n"
                  "  access_log " +
                  d +
                  "/access.log;\n"
                  "  client_body_temp_path " +
                  d +
                  "/tmp/body;\n"
                  "  proxy_temp_path " +
                  d +
                  "/tmp/proxy;\n"
                  "  fastcgi_temp_path " +
                  d +
                  "/tmp/fastcgi;\n"
                  "  uwsgi_temp_path " +
                  d +
                  "/tmp/uwsgi;\n"
                  "  scgi_temp_path " +
                  d +
                  "/tmp/scgi;\n"
                  "  include " +
                  d +
                  "/site.conf;\n"
                  "}\n");
    fs::create_directories(dir / "tmp");
    return "";
  }

  // `nginx -t` on the rendered configuration.
  CommandResult Test(const std::string& nginx) const {
    return RunCommand("'" + nginx + "' -t " + Args());
  }

  // Starts nginx in the foreground (a child of the test) and waits until it accepts TLS
  // connections; "" or the error (with the error log).
  std::string Start(const std::string& nginx, uint16_t https_port) {
    pid_ = fork();
    if (pid_ < 0) return "fork failed";
    if (pid_ == 0) {
      const std::string prefix = dir_.string(), conf = (dir_ / "nginx.conf").string(),
                        log = (dir_ / "error.log").string();
      execl(nginx.c_str(), nginx.c_str(), "-p", prefix.c_str(), "-c", conf.c_str(), "-e",
            log.c_str(), "-g", "daemon off;", static_cast<char*>(nullptr));
      _exit(127);
    }
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(15);
    while (std::chrono::steady_clock::now() < deadline) {
      if (waitpid(pid_, nullptr, WNOHANG) == pid_) {
        pid_ = -1;
        return "nginx exited: " + ReadFile(dir_ / "error.log");
      }
      boost::asio::io_context ioc;
      boost::asio::ip::tcp::socket socket(ioc);
      boost::system::error_code ec;
      socket.connect({boost::asio::ip::make_address("127.0.0.1"), https_port}, ec);
      if (!ec) return "";
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return "nginx did not listen within 15 s: " + ReadFile(dir_ / "error.log");
  }

  // Fast shutdown (SIGTERM), as systemd stops it.
  void Stop() {
    if (pid_ <= 0) return;
    kill(pid_, SIGTERM);
    for (int i = 0; i < 200 && waitpid(pid_, nullptr, WNOHANG) != pid_; ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(25));
      if (i == 199) {
        kill(pid_, SIGKILL);
        waitpid(pid_, nullptr, 0);
      }
    }
    pid_ = -1;
  }

  std::string access_log() const { return ReadFile(dir_ / "access.log"); }
  std::string error_log() const { return ReadFile(dir_ / "error.log"); }

 private:
  std::string Args() const {
    return "-p '" + dir_.string() + "' -c '" + (dir_ / "nginx.conf").string() + "' -e '" +
           (dir_ / "error.log").string() + "'";
  }

  fs::path dir_;
  pid_t pid_ = -1;
};

}  // namespace octoscope::deploy::testing

#endif  // OCTOSCOPE_TESTS_DEPLOY_NGINX_PROXY_H_
