#include "server/metrics_text.h"

#include <sstream>

#include "server/http_connections.h"

namespace btfvq::server {

std::string metrics_text(const MetricsSnapshot& m) {
  std::map<std::string, int> by_state;  // by name, so that the labels come out sorted
  for (JobState s : kJobStates) by_state[to_string(s)] = m.jobs.count(s) ? m.jobs.at(s) : 0;
  std::ostringstream out;
  out << "# HELP btfvq_jobs Jobs by state.\n# TYPE btfvq_jobs gauge\n";
  for (const auto& [state, n] : by_state) out << "btfvq_jobs{state=\"" << state << "\"} " << n << "\n";
  out << "# HELP btfvq_queue_length Jobs waiting for a worker.\n# TYPE btfvq_queue_length gauge\n"
      << "btfvq_queue_length " << by_state[to_string(JobState::queued)] << "\n";
  out << "# HELP btfvq_workers Configured worker count.\n# TYPE btfvq_workers gauge\nbtfvq_workers " << m.workers
      << "\n";
  out << "# HELP btfvq_bytes_served_total Database bytes sent to clients.\n# TYPE btfvq_bytes_served_total counter\n"
      << "btfvq_bytes_served_total " << m.bytes_served << "\n";
  out << "# HELP btfvq_bytes_uploaded_total Upload bytes received.\n# TYPE btfvq_bytes_uploaded_total counter\n"
      << "btfvq_bytes_uploaded_total " << m.bytes_uploaded << "\n";
  out << "# HELP btfvq_databases Databases in the catalogue.\n# TYPE btfvq_databases gauge\n"
      << "btfvq_databases " << m.databases << "\n";
  out << "# HELP btfvq_stage_seconds_total Time spent by jobs in each stage (phase1/2/3, ...).\n"
      << "# TYPE btfvq_stage_seconds_total counter\n";
  for (const auto& [stage, s] : m.stage_seconds) out << "btfvq_stage_seconds_total{stage=\"" << stage << "\"} " << s << "\n";
  return out.str();
}

std::string connection_metrics_text(const ConnectionCounts& c) {
  std::ostringstream out;
  out << "# HELP btfvq_http_connections Connections open now.\n# TYPE btfvq_http_connections gauge\n"
      << "btfvq_http_connections " << c.open << "\n";
  out << "# HELP btfvq_http_connections_refused_total Connections answered 503 beyond a connection cap.\n"
      << "# TYPE btfvq_http_connections_refused_total counter\n"
      << "btfvq_http_connections_refused_total " << c.refused << "\n";
  out << "# HELP btfvq_http_requests_timed_out_total Requests whose headers or body did not arrive in time.\n"
      << "# TYPE btfvq_http_requests_timed_out_total counter\n"
      << "btfvq_http_requests_timed_out_total " << c.timed_out << "\n";
  return out.str();
}

}  // namespace btfvq::server
