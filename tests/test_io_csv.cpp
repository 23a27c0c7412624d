// Tests of the file I/O layer (src/data/io_*.cpp), CSV: the tables in data/ and the parser's details
// and malformed input.
#include <doctest/doctest.h>

#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "common.hpp"
#include "io_common.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using namespace qdo;
using namespace qdo::test::io_suite;
using qdo::test::input_error_of;
using qdo::test::slurp;

namespace {

const fs::path kDataDir = fs::path(__FILE__).parent_path().parent_path() / "data";

}  // namespace

TEST_SUITE("io") {
  TEST_CASE("CSV tables from data/") {
    const CsvTable srf = read_csv((kDataDir / "srf_FLIR_GS3-U3-41S4C.csv").string());
    CHECK(srf.header == std::vector<std::string>{"wavelength_nm", "R", "G", "B"});
    REQUIRE(srf.column("R").size() == 31);
    CHECK(srf.column("R")[0] == 7.111793475);
    CHECK(srf.column("wavelength_nm")[0] == 400);
    CHECK(srf.column("wavelength_nm")[30] == 700);
    CHECK(srf.comments.size() == 4);

    const CsvTable cc = read_csv((kDataDir / "colorchecker24_400-700nm_10nm.csv").string());
    REQUIRE(cc.header.size() == 32);
    CHECK(cc.header[0] == "name");
    REQUIRE(cc.raw[0].size() == 24);
    CHECK(cc.raw[0][0] == "dark skin");
    CHECK(std::isnan(cc.columns[0][0]));
    CHECK(cc.column("400")[0] == 0.061);
    CHECK(cc.column("700")[0] == 0.182);
    const std::string msg = input_error_of([&] { cc.column("750"); });
    CHECK(contains(msg, "750"));
    CHECK(contains(msg, "name, 400, 410"));

    const CsvTable d65 = read_csv((kDataDir / "cie_d65_400-700nm_10nm.csv").string());
    CHECK(d65.column("relative_power")[0] == 82.7549);
  }

  TEST_CASE("CSV parsing details and malformed input") {
    const CsvTable t = parse_csv("# c1\n\n a , b \n1, 2\r\n  \n# c2\n3,x\n", "mem");
    CHECK(t.header == std::vector<std::string>{"a", "b"});
    CHECK(t.comments == std::vector<std::string>{"c1", "c2"});
    CHECK(t.column("a") == std::vector<double>{1, 3});
    CHECK(t.columns[1][0] == 2);
    CHECK(std::isnan(t.columns[1][1]));
    CHECK(t.raw[1][1] == "x");

    std::string msg = input_error_of([] { parse_csv("# c\na,b\n1,2\n3,4,5\n", "ragged.csv"); });
    CHECK(contains(msg, "ragged.csv"));
    CHECK(contains(msg, "line 4"));
    msg = input_error_of([] { parse_csv("# only comments\n", "empty.csv"); });
    CHECK(contains(msg, "empty.csv"));
    CHECK_THROWS_AS(read_csv("/nonexistent/table.csv"), InputError);
  }

  TEST_CASE("CSV writing quotes what must be quoted; parse_csv reads every cell back") {
    // Labels qdo writes into tables (decoder specs, scene file names, scenario names) may hold
    // commas, quotes, line breaks, blanks at either end or a leading '#'.
    const std::vector<std::string> hostile = {"do@resunet:depth=4,root=16", "a \"quoted\" name", "two\nlines", "cr\r\nlf",
                                              " padded ", "#not a comment", "plain", "", ",", "\"", "tab\tinside"};
    CsvText t({"label", "value"});
    for (std::size_t i = 0; i < hostile.size(); ++i) t.row({hostile[i], csv_number(double(i) + 0.5)});
    const CsvTable back = parse_csv(t.str(), "written");
    REQUIRE(back.header == std::vector<std::string>{"label", "value"});
    REQUIRE(back.raw[0].size() == hostile.size());
    for (std::size_t i = 0; i < hostile.size(); ++i) {
      CAPTURE(i);
      CHECK(back.raw[0][i] == hostile[i]);
      CHECK(back.columns[1][i] == double(i) + 0.5);
    }
    CHECK(csv_field("plain") == "plain");
    CHECK(csv_field("a,b") == "\"a,b\"");
    CHECK(csv_field("say \"hi\"") == "\"say \"\"hi\"\"\"");
    CHECK(csv_number(1.0 / 3.0) == "0.333333");
    CHECK(csv_number(1.0 / 3.0, 8) == "0.33333333");
    // A row of the wrong width is a programming error, never a ragged file.
    CHECK_THROWS_AS(t.row({"only one"}), Error);
    // Quoted headers (spreadsheet exports) name their columns without the quotes.
    CHECK(parse_csv("\"wavelength_nm\",\"r\"\n400,0.5\n", "export").column("r") == std::vector<double>{0.5});
    // Malformed quoting is refused naming the file and the line.
    std::string msg = input_error_of([] { parse_csv("a,b\n\"open,1\n", "unclosed.csv"); });
    CHECK(contains(msg, "unclosed.csv"));
    CHECK(contains(msg, "line 2"));
    CHECK(contains(msg, "not closed"));
    msg = input_error_of([] { parse_csv("a,b\n\"x\"y,1\n", "after.csv"); });
    CHECK(contains(msg, "after.csv"));
    CHECK(contains(msg, "after a quoted cell"));
    msg = input_error_of([] { parse_csv("a,b\n5\"in,1\n", "inside.csv"); });
    CHECK(contains(msg, "line 2"));
    CHECK(contains(msg, "quote inside an unquoted cell"));
    // A line count that includes the lines inside quoted cells.
    msg = input_error_of([] { parse_csv("a,b\n\"x\ny\",1\n1,2,3\n", "count.csv"); });
    CHECK(contains(msg, "line 4"));
  }
}
