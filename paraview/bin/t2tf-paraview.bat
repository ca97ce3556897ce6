@echo off
rem Start ParaView with the t2tf plugin loaded (Windows):
rem     t2tf-paraview.bat [--venv DIR] [paraview^|pvpython^|pvbatch^|pvserver] [ARGS...]
rem
rem The plugin's folder goes on PV_PLUGIN_PATH (ParaView loads every .py file there at start-up).
rem A t2tf.exe built in this repository (target\release\t2tf.exe, or the Windows cross build)
rem goes at the end of PATH, so an installed t2tf or T2TF_BIN wins. ParaView's programs come
rem from PATH, or from PARAVIEW_BIN, its bin folder (for example
rem "C:\Program Files\ParaView 5.13.0\bin"). --venv DIR puts a virtual environment's packages
rem (DIR\Lib\site-packages) on PYTHONPATH, so ParaView's Python runs t2tf in-process from a
rem `pip install .` made there. The same as bin/t2tf-paraview on Linux and macOS.
setlocal EnableExtensions
for %%I in ("%~dp0..") do set "plugin_dir=%%~fI"
for %%I in ("%plugin_dir%\..") do set "repo=%%~fI"
if defined PV_PLUGIN_PATH (
    set "PV_PLUGIN_PATH=%plugin_dir%;%PV_PLUGIN_PATH%"
) else (
    set "PV_PLUGIN_PATH=%plugin_dir%"
)
if exist "%repo%\target\release\t2tf.exe" (
    set "PATH=%PATH%;%repo%\target\release"
) else if exist "%repo%\target\x86_64-pc-windows-gnu\release\t2tf.exe" (
    set "PATH=%PATH%;%repo%\target\x86_64-pc-windows-gnu\release"
)

if /i not "%~1"=="--venv" goto program
if "%~2"=="" (
    echo t2tf-paraview: --venv needs a folder 1>&2
    exit /b 2
)
if not exist "%~2\Lib\site-packages\" (
    echo t2tf-paraview: %~2: not a virtual environment ^(no Lib\site-packages^); make one with python -m venv %~2 1>&2
    exit /b 2
)
if defined PYTHONPATH (
    set "PYTHONPATH=%PYTHONPATH%;%~2\Lib\site-packages"
) else (
    set "PYTHONPATH=%~2\Lib\site-packages"
)
shift
shift

:program
set "program=paraview"
set "first=%~1"
if /i "%first%"=="paraview" goto named
if /i "%first%"=="pvpython" goto named
if /i "%first%"=="pvbatch" goto named
if /i "%first%"=="pvserver" goto named
goto start
:named
set "program=%first%"
shift

:start
set "args="
:collect
if "%~1"=="" goto run
set args=%args% %1
shift
goto collect

:run
if defined PARAVIEW_BIN set "program=%PARAVIEW_BIN%\%program%"
"%program%" %args%
exit /b %ERRORLEVEL%
